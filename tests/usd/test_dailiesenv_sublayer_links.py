"""A shot's sublayer that is a link to nothing or a link loop, filled without --strict: the
warning line says what it is (it said "not a regular file", which names a pipe or device)."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "sh010_walk.usda"


@pytest.mark.parametrize("kind", ["a link to nothing", "a link loop"])
def test_a_broken_link_sublayer_is_warned_of_as_what_it_is(tmp_path, kind):
    shutil.copy(EXAMPLE, tmp_path / "walk.usda")
    link = tmp_path / "extra.usda"
    if kind == "a link to nothing":
        link.symlink_to(tmp_path / "gone.usda")
    else:
        link.symlink_to(tmp_path / "other.usda")
        (tmp_path / "other.usda").symlink_to(link)
    shot = tmp_path / "sh020.usda"
    shot.write_text(
        "#usda 1.0\n(\n    subLayers = [\n        @./extra.usda@,\n        @./walk.usda@\n    ]\n)\n"
    )
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "fill-local", str(shot), "--model", "interp",
                        "--out-dir", str(tmp_path / "out")], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    warned = [ln for ln in r.stderr.splitlines() if ln.startswith("tween: warning: ") and str(link) in ln]
    assert len(warned) == 1, r.stderr
    assert f"{link}: {kind}" in warned[0] and "not a regular file" not in warned[0], warned[0]
    assert warned[0].endswith("the shot is filled without it")
