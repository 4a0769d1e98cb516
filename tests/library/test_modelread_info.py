"""`tween library info` says a library is fine only where a fill takes it: before, a manifest
whose ``skeleton`` lost a joint name (or is at another frame rate) passed info, and every fill
with the library then refused it."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from cli_contract import refused, succeeded

from pipeline.library.infer import LibraryInbetweener
from pipeline.library.store import MANIFEST, LibraryError

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ROOT / "models" / "default" / "library"


def _skeleton_without_hips(m: dict) -> None:
    m["skeleton"] = m["skeleton"][1:]


def _skeleton_reordered(m: dict) -> None:
    m["skeleton"] = m["skeleton"][::-1]


def _skeleton_renamed(m: dict) -> None:
    m["skeleton"] = ["Pelvis", *m["skeleton"][1:]]


def _skeleton_left_out(m: dict) -> None:
    del m["skeleton"]


def _at_60_fps(m: dict) -> None:
    m["fps"] = 60.0


@pytest.mark.parametrize(
    "edit, says",
    [
        (_skeleton_without_hips, "its takes are on another skeleton than the model's (joint 'Hips' missing)"),
        (_skeleton_reordered, "its takes are on another skeleton than the model's (21 names for"),
        (_skeleton_renamed, "(joint 'Hips' missing)"),
        (_skeleton_left_out, "and 20 more missing"),
        (_at_60_fps, "60 fps, the fill works at 30"),
    ],
    ids=["lost-a-name", "reordered", "renamed", "none", "fps"],
)
def test_library_info_refuses_what_the_fill_refuses(tmp_path, capsys, edit, says):
    copy = tmp_path / "lib"
    shutil.copytree(SHIPPED, copy)
    succeeded(["library", "info", copy], capsys)  # the shipped one: fine for both
    LibraryInbetweener(copy)
    m = json.loads((copy / MANIFEST).read_text())
    edit(m)
    (copy / MANIFEST).write_text(json.dumps(m))
    with pytest.raises(LibraryError):  # the fill refuses it ...
        LibraryInbetweener(copy)
    line = refused(["library", "info", copy], capsys, tmp_path)  # ... and so does info
    assert line.startswith(f"tween: error: {copy / MANIFEST}: ") and says in line, line
