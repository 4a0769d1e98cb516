"""A shot whose sublayers, references or payloads are missing: said, recorded, or refused."""

from __future__ import annotations

import subprocess
import sys

import pytest
from pxr import Sdf, Usd
from usd_fixtures import bandai_shot, tree_hashes

from pipeline.errors import ShotError
from pipeline.fill.api import FillOptions, fill_shot


@pytest.fixture
def broken(tmp_path):
    """A blocked shot that sublayers a lighting layer, references a prop and payloads a set,
    none of which exist (USD composes it without them and only warns)."""
    shot = bandai_shot(tmp_path / "shots" / "sh040.usda", frames=31)
    layer = Sdf.Layer.FindOrOpen(str(shot))
    layer.subLayerPaths.append("./lighting/sh040_light.usda")
    stage = Usd.Stage.Open(layer)
    stage.DefinePrim("/World/Chair").GetReferences().AddReference("./props/chair.usda")
    stage.DefinePrim("/World/Set").GetPayloads().AddPayload("./sets/kitchen.usd")
    layer.Save()
    folder = shot.parent
    return shot, [str(folder / "lighting/sh040_light.usda"), str(folder / "props/chair.usda"),
                  str(folder / "sets/kitchen.usd")]  # fmt: skip


def test_missing_assets_are_said_once_each_and_recorded(broken, tmp_path, capfd):
    shot, missing = broken
    res = fill_shot(str(shot), FillOptions(model="interp", out_dir=str(tmp_path / "o")))
    assert res["missing_assets"] == sorted(missing)
    err = capfd.readouterr().err
    for asset in missing:
        lines = [ln for ln in err.splitlines() if asset in ln]
        assert len(lines) == 1 and lines[0].startswith(f"tween: warning: {shot}: ")


def test_strict_refuses_before_writing_anything(broken, tmp_path):
    shot, missing = broken
    before = tree_hashes(shot.parent)
    with pytest.raises(ShotError, match=r"missing sublayer, reference or payload .* and 2 more \(--strict\)"):
        fill_shot(str(shot), FillOptions(model="interp", strict=True, out_dir=str(tmp_path / "o")))
    assert not (tmp_path / "o").exists() and tree_hashes(shot.parent) == before
    # The farm's client refuses too, before any farm starts: one line, exit 2.
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "fill", str(shot), "--strict", "--model", "interp",
                        "--out-dir", str(tmp_path / "o")], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--strict" in r.stderr
    assert not (tmp_path / "o").exists()


def test_a_whole_shot_has_nothing_missing(tmp_path, capfd):
    shot = bandai_shot(tmp_path / "sh050.usda", frames=31)
    res = fill_shot(str(shot), FillOptions(model="interp", out_dir=str(tmp_path / "o")))
    assert res["missing_assets"] == [] and "warning" not in capfd.readouterr().err
