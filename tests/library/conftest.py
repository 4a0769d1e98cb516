"""The library tests' shared takes and library (built once a session)."""

from __future__ import annotations

import shutil

import pytest
from library_fixtures import BANDAI, CMU_TAKE

from pipeline.library.build import build


@pytest.fixture(scope="session")
def takes(data_dir, tmp_path_factory):
    folder = tmp_path_factory.mktemp("takes")
    for name in BANDAI:
        shutil.copy(data_dir / "bandai_namco" / "dataset-2" / name, folder / name)
    (folder / "cmu").mkdir()
    shutil.copy(data_dir / "cmu_iclone" / CMU_TAKE, folder / "cmu" / CMU_TAKE)
    return folder


@pytest.fixture(scope="session")
def library(takes, tmp_path_factory):
    out = tmp_path_factory.mktemp("libs") / "studio"
    res = build(takes, out, licence="studio-internal", progress=False)
    assert res["added"] == 4 and not res["failed"]
    return out
