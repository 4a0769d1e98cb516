"""The studio bench (pipeline/bench/studio.py): a studio's take converted, blocked, filled
through the fill API and scored in its own rig's joints."""

import json
import tempfile
from pathlib import Path

import numpy as np
import pytest

from pipeline.bench import studio
from pipeline.bench.heldout import cmu_files
from pipeline.errors import TweenError
from pipeline.fill.api import FillOptions, fill_shot
from pipeline.motion.bvh import read_bvh
from pipeline.motion.clip import resample
from pipeline.usd.convert import write_shot


def test_review_positions_are_the_capture_at_the_keys_on_the_rig():
    take = cmu_files((7,))[0]
    motion = read_bvh(take).slice(0, 120)
    at30 = resample(motion, studio.FPS)
    truth = at30.positions() * at30.skeleton.meters_per_unit * 100.0
    with tempfile.TemporaryDirectory() as tmp:
        shot = write_shot(motion, Path(tmp) / "s.usda", fps=studio.FPS, keys_every=10)
        out = fill_shot(shot, FillOptions(model="interp", out_dir=str(Path(tmp) / "o")))
        pos = studio.review_positions(out["review"], len(at30))
    assert pos.shape == truth.shape and pos.shape[1] >= 100  # every joint of the production rig
    keys = np.r_[np.arange(0, len(at30), 10), len(at30) - 1]
    err = np.linalg.norm(pos - truth, axis=-1)
    assert err[keys].max() < 1e-3  # cm: the keys are the capture
    assert 0.1 < np.delete(err, keys, 0).mean() < 50.0  # the fill between them is not


def test_studio_bench_end_to_end(tmp_path, capsys):
    argv = ["--subjects", "7", "--limit", "1", "--every", "10", "--max-frames", "90"]
    assert studio.main([*argv, "--out", str(tmp_path)]) == 0
    rep = json.loads((tmp_path / "studio.json").read_text())
    table = rep["error_cm"]["10"]
    assert set(table) == set(studio.METHODS)
    for m in studio.METHODS:
        assert 0 < table[m]["mapped"] < 50 and 0 < table[m]["all"] < 50
    take = next(iter(rep["per_take"]["10"].values()))
    assert take["frames"] <= 90 and take["methods"]["default"]["trust"]["novelty_cm"] > 0
    # The trusted fill is near the better of the network's and the spline's (this walk:
    # the network, 1.047x the spline on the mapped joints, 1.000x on all of them).
    for part in ("mapped", "all"):
        assert table["default"][part] <= 1.10 * min(table["network"][part], table["spline"][part])
    assert "| 10 | mapped |" in capsys.readouterr().out
    with pytest.raises(TweenError, match="--methods: unknown linear"):
        studio.main(["--methods", "linear"])


def test_a_leading_glitch_frame_is_found_and_only_that():
    """Subject 7's takes start with one frame metres away from the next: dropped; a take
    without one keeps every frame, and a jump is planted to check the rule itself."""
    glitched = next(f for f in cmu_files((7,)) if f.name.startswith("007_06"))
    clean = next(f for f in cmu_files((7,)) if f.name.startswith("007_01"))
    assert studio.leading_glitch(read_bvh(glitched)) == 1
    m = read_bvh(clean)
    assert studio.leading_glitch(m) == 0
    m.root_positions[:5] += 500.0  # five frames 5 m away at the start: all five dropped
    assert studio.leading_glitch(m) == 5


def test_studio_bench_curve_is_the_trusted_fills_curve_alone(tmp_path):
    """``--methods curve``: the default model with ``--trust spline``, every gap the trusted
    fill's curve (not the clamped spline), asked for by name only."""
    argv = ["--subjects", "7", "--limit", "1", "--every", "10", "--max-frames", "90"]
    assert studio.main([*argv, "--methods", "curve,spline", "--out", str(tmp_path)]) == 0
    rep = json.loads((tmp_path / "studio.json").read_text())
    take = next(iter(rep["per_take"]["10"].values()))["methods"]
    assert take["curve"]["trust"]["choice"] == "spline" and "curve" not in studio.METHODS
    assert take["curve"]["mapped_sum"] != take["spline"]["mapped_sum"]  # keys every 10: dense
