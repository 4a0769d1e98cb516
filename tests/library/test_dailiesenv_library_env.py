"""`tween fill-local` and the studio's library setting: TWEEN_LIBRARY is every fill's library
when it names none (as `tween fill`'s farm setting is), `--library` wins over it, and a bad
one is one line naming the variable and the path."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from pxr import Sdf

from pipeline.library.store import open_library

SHOT = Path(__file__).resolve().parents[2] / "examples" / "sh010_walk.usda"


def _run(*args, library: str | None):
    env = {k: v for k, v in os.environ.items() if k != "TWEEN_LIBRARY"}
    if library is not None:
        env["TWEEN_LIBRARY"] = library
    return subprocess.run([sys.executable, "-m", "pipeline.cli", *map(str, args)], capture_output=True,
                          text=True, env=env)  # fmt: skip


def _one_line(r, *names: str) -> None:
    assert r.returncode == 2 and r.stdout == "", (r.stdout, r.stderr)
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("tween: error: "), r.stderr
    assert all(n in r.stderr for n in names), r.stderr


def test_fill_local_fills_from_the_library_tween_library_names(library, tmp_path):
    """Before: fill-local ignored the variable its --library help names as the default."""
    r = _run("fill-local", SHOT, "--out-dir", tmp_path / "out", library=str(library))
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    lib = open_library(library)
    assert res["model"] == "library:studio" and res["model_hash"] == f"library-{lib.hash}"
    # The layer records it (here the network probed beside it decided every gap).
    data = Sdf.Layer.FindOrOpen(res["layer"]).customLayerData["tween"]
    assert data["model"] == "library:studio" and data["modelHash"] == f"library-{lib.hash}"
    assert data["licence"]["library:studio"] == "studio-internal"
    # --library wins over the variable (here naming no library: it is not even read).
    r = _run("fill-local", SHOT, "--library", library, "--out-dir", tmp_path / "own",
             library=str(tmp_path / "nowhere"))  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["model_hash"] == f"library-{lib.hash}"
    # A fill asking for a curve gets the curve, as the farm's jobs do: no network to probe beside it.
    r = _run("fill-local", SHOT, "--model", "spline", "--out-dir", tmp_path / "curve", library=str(library))
    assert r.returncode == 0, r.stderr
    assert not json.loads(r.stdout)["model"].startswith("library:")


def test_a_bad_tween_library_is_one_line_naming_the_variable_and_the_path(tmp_path):
    out = tmp_path / "out"
    missing = tmp_path / "no-library"
    _one_line(_run("fill-local", SHOT, "--out-dir", out, library=str(missing)),
              f"TWEEN_LIBRARY={missing}", "no such library folder")  # fmt: skip
    (tmp_path / "plain").mkdir()
    _one_line(_run("fill-local", SHOT, "--out-dir", out, library=str(tmp_path / "plain")),
              f"TWEEN_LIBRARY={tmp_path / 'plain'}", "not a library")  # fmt: skip
    _one_line(_run("fill-local", SHOT, "--out-dir", out, library="  "), "TWEEN_LIBRARY='  '", "empty")
    assert not out.exists()
