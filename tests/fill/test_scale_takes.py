"""A fill of several takes in one process reads the shot once: each take read (and checked)
every sample of the shot again, so a 30,000-frame shot sampled on every frame cost 3.5 s per
take before any filling (``fill_shot`` hands its validated plan to every take)."""

from __future__ import annotations

from pathlib import Path

from usd_fixtures import bandai_shot

import pipeline.fill.plan as plan_mod
from pipeline.fill import FillOptions, fill_shot


def test_takes_share_one_reading_of_the_shot(tmp_path, monkeypatch):
    shot = bandai_shot(tmp_path / "sh010.usda", frames=31, keys_every=10)
    reads = []
    real = plan_mod.read_shot
    monkeypatch.setattr(plan_mod, "read_shot", lambda *a, **k: reads.append(a) or real(*a, **k))
    res = fill_shot(str(shot), FillOptions(model="interp", takes=3, out_dir=str(tmp_path / "out")))
    assert len(reads) == 1, f"the shot was read {len(reads)} times for 3 takes"
    assert Path(res["layer"]).name == "sh010.tween.v001.usda" and Path(res["layer"]).is_file()
    assert res["takes"] == 3
