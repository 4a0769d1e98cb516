"""`tween review SHOT` finds the shot's latest fill by itself (and says so)."""

import json
import subprocess
import sys

from usd_fixtures import bandai_shot

from pipeline.fill.api import FillOptions, fill_shot


def _review(cwd, *args):
    return subprocess.run([sys.executable, "-m", "pipeline.cli", "review", *map(str, args), "--no-frames",
                           "--size", "160x96"], cwd=cwd, capture_output=True, text=True, timeout=300)  # fmt: skip


def test_review_of_a_shot_renders_its_latest_fill(tmp_path):
    shot = bandai_shot(tmp_path / "sh060.usda", frames=21)
    r = _review(tmp_path, shot)  # no fill yet: the shot as it is, said
    assert r.returncode == 0, r.stderr
    assert "no fill of it yet" in r.stderr
    fill_shot(str(shot), FillOptions(model="interp"))
    latest = fill_shot(str(shot), FillOptions(model="interp", takes=2))  # v002, two takes
    r = _review(tmp_path, shot, "--take", 1)
    assert r.returncode == 0, r.stderr
    assert f"its latest fill, {latest['review']}" in r.stderr
    out = json.loads(r.stdout)
    assert out["mp4"].endswith("sh060_v002_take1.mp4") and (tmp_path / out["mp4"]).stat().st_size > 1000
