"""A library fill carries the library's licence beside the network's (issue 30, item 4)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from library_fixtures import CMU_TAKE
from pxr import Sdf, Usd
from usd_fixtures import FILLED

from pipeline.motion.bvh import read_bvh
from pipeline.usd.convert import write_shot
from usd_schemas import tokens


@pytest.mark.parametrize("trust", ["auto", "model"])
def test_a_library_fill_names_the_librarys_licence_and_the_networks(library, data_dir, tmp_path, trust):
    m = read_bvh(data_dir / "cmu_iclone" / CMU_TAKE).slice(0, 61)
    shot = write_shot(m, tmp_path / "sh040.usda", fps=30, keys_every=10)
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "fill-local", str(shot), "--library", str(library),
                        "--trust", trust, "--out-dir", str(tmp_path / "out")], capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    # The library's takes and the network probed beside them: each under its own terms. With
    # --trust model the library alone fills (nothing is probed), so the network is not named.
    want = {"library:studio": "studio-internal"}
    if trust == "auto":
        want["tween-bandai-v5.3"] = "CC BY-NC 4.0"
    assert res["licence"] == want
    assert dict(Sdf.Layer.FindOrOpen(res["layer"]).customLayerData["tween"]["licence"]) == want
    stage = Usd.Stage.Open(res["layer"])
    line = stage.GetPrimAtPath(FILLED).GetAttribute(tokens.MODEL_LICENCE).Get()
    assert line == "; ".join(f"{k}: {v}" for k, v in want.items())
    assert ("probed beside it" in r.stderr) == (trust == "auto")
