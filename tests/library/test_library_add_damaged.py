"""`library build --add` checks the library as `library info` does before it appends: takes
added to a library whose arrays are damaged went down with it (rc 0, still refused by info)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from library_fixtures import BANDAI, HELD_OUT

from pipeline.library.build import build
from pipeline.library.store import LibraryError


def test_add_to_a_damaged_library_is_refused_and_leaves_it_as_it_was(data_dir, tmp_path):
    clips = data_dir / "bandai_namco" / "dataset-2"
    first, second = tmp_path / "first", tmp_path / "second"
    first.mkdir(), second.mkdir()
    shutil.copy(clips / BANDAI[0], first / BANDAI[0])
    shutil.copy(clips / HELD_OUT, second / HELD_OUT)
    lib = tmp_path / "lib"
    assert build(first, lib, progress=False)["added"] == 1
    features = np.fromfile(lib / "features.bin", np.float32)
    features[100:200] = np.nan
    features.tofile(lib / "features.bin")
    before = {p.name: p.read_bytes() for p in sorted(lib.iterdir())}

    with pytest.raises(LibraryError) as e:
        build(second, lib, add=True, progress=False)
    assert str(lib / "features.bin") in str(e.value) and "not finite" in str(e.value)
    assert {p.name: p.read_bytes() for p in sorted(lib.iterdir())} == before
