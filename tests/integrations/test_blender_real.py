"""The Blender extension in a real headless Blender (``bpy`` from PyPI, Blender as a Python
module), filling on the project's own embedded farm: tests/integrations/blender_check.py.

``bpy`` is not a project dependency (1 GB, one Python version): this runs where a Python with
``bpy`` is named by ``TWEEN_BPY_PYTHON`` (``python3.11 -m venv V && V/bin/pip install bpy``), or
where this interpreter has it, and is skipped with the reason printed anywhere else.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
CHECK = HERE / "blender_check.py"


def _bpy_python() -> str | None:
    named = os.environ.get("TWEEN_BPY_PYTHON")
    if named:
        return named if Path(named).is_file() else None
    return sys.executable if importlib.util.find_spec("bpy") else None


def test_fill_from_blender_for_real(tmp_path):
    py = _bpy_python()
    tween = Path(sys.executable).parent / "tween"
    if py is None:
        why = "no Python with bpy: set TWEEN_BPY_PYTHON to one (pip install bpy into a Python 3.11 venv)"
        print(f"SKIPPED: {why}", file=sys.stderr)
        pytest.skip(why)
    if not tween.is_file():
        pytest.skip(f"no tween executable beside {sys.executable}")
    # not the user's Blender preferences, nor this machine's farm: the embedded one, its own cache
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "blender"), TWEEN_FARM_CONFIG=os.devnull,
               TWEEN_CACHE=str(tmp_path / "cache"))  # fmt: skip
    cmd = [py, str(CHECK), "--tween", str(tween), "--out", str(tmp_path / "out"), "--frames", "121",
           "--takes", "2", "--actions"]  # fmt: skip
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=1500)
    assert res.returncode == 0, (res.stdout + res.stderr)[-4000:]
    rows = [json.loads(ln) for ln in res.stdout.splitlines() if ln.startswith("{")]
    by = {r["clip"]: r for r in rows if "clip" in r}
    assert set(by) == {"bandai", "cmu_iclone", "rigify_named"}
    for r in by.values():
        assert len(r["takes"]) == 2 and all(t["keys_exact"] > 0 for t in r["takes"])
        assert all(t["max_channel_change_vs_bezier"] > 1e-3 for t in r["takes"])
    # The model's walk beats Blender's Bezier on the clip it never trained on, on the Bandai
    # rig and on the same rig named the Blender way (the mapping finds it by itself).
    for clip in ("bandai", "rigify_named"):
        assert by[clip]["takes"][0]["error_cm"] < by[clip]["bezier_cm"]
    for r in by.values():  # the partial key (the left arm alone) went through as tween:keyedJoints
        assert r["partial_key"]["fill_off_by_deg"] < 5.0, r["partial_key"]
    actions = next(r for r in rows if "approve" in r)
    assert actions["fetched"] == 2
    assert actions["approve"] and actions["publish"].endswith(".usda") and actions["refused"].count("\n") == 0
