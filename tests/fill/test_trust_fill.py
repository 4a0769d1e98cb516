"""The fill decides, per character, how far to trust the network against the spline."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from usd_fixtures import cmu_shot

from pipeline.errors import TweenError
from pipeline.fill.api import FillOptions, fill_shot

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "sh010_walk.usda"
ANIM = "/World/Walker/Skel/Anim"


def _rotations(review: str, anim: str) -> dict:
    from pxr import Usd

    stage = Usd.Stage.Open(review)
    attr = stage.GetPrimAtPath(anim + "_tween").GetAttribute("rotations")
    out = {t: np.array(attr.Get(t)) for t in attr.GetTimeSamples()}
    del stage
    return out


@pytest.fixture()
def example(tmp_path):
    shutil.copy(EXAMPLE, tmp_path / EXAMPLE.name)
    return tmp_path / EXAMPLE.name


def test_auto_trust_is_decided_recorded_and_said(example, tmp_path, capfd):
    from pxr import Usd

    res = fill_shot(str(example), FillOptions(out_dir=str(tmp_path / "auto")))
    d = res["trust"][ANIM]
    assert d["trust"] == "auto" and d["choice"] in ("model", "blend", "spline") and 0 <= d["weight"] <= 1
    assert len(d["probes"]) >= 1 and d["model_error_cm"] is not None and d["spline_error_cm"] is not None
    stage = Usd.Stage.Open(res["layer"])
    spec = stage.GetPrimAtPath(ANIM + "_tween")
    assert spec.GetAttribute("tween:trust").Get() == d["choice"]
    assert spec.GetAttribute("tween:trustWeight").Get() == pytest.approx(d["weight"])
    evidence = json.loads(spec.GetAttribute("tween:trustEvidence").Get())
    assert evidence["probes"] == d["probes"]
    # The keys' novelty against the model's pose bank: the example is an eval walk, familiar.
    assert evidence["novelty_cm"] == d["novelty_cm"] < 3.0 and evidence["familiarity"] == 1.0
    err = capfd.readouterr().err
    assert f"{ANIM}: trust {d['choice']} (model weight {d['weight']:.2f}" in err
    assert f"keys {d['novelty_cm']:.1f} cm from its training poses (familiarity 1.00)" in err


def test_on_the_models_own_data_auto_is_the_model_bit_for_bit(example, tmp_path):
    """The example walk (an eval clip on the model skeleton): the probes pick the network,
    and the fill is the unchecked model's exactly."""
    auto = fill_shot(str(example), FillOptions(out_dir=str(tmp_path / "a")))
    model = fill_shot(str(example), FillOptions(out_dir=str(tmp_path / "m"), trust="model"))
    assert auto["trust"][ANIM]["choice"] == "model"
    assert model["trust"][ANIM]["probes"] == [] and model["trust"][ANIM]["trust"] == "model"
    a, m = _rotations(auto["review"], ANIM), _rotations(model["review"], ANIM)
    assert a.keys() == m.keys() and all(np.array_equal(a[t], m[t]) for t in a)


def test_trust_spline_overrides_and_keeps_the_keys(example, tmp_path):
    from pxr import Usd

    model = fill_shot(str(example), FillOptions(out_dir=str(tmp_path / "m"), trust="model"))
    spline = fill_shot(str(example), FillOptions(out_dir=str(tmp_path / "s"), trust="spline"))
    assert spline["trust"][ANIM]["choice"] == "spline" and spline["trust"][ANIM]["weight"] == 0.0
    m, s = _rotations(model["review"], ANIM), _rotations(spline["review"], ANIM)
    assert any(not np.array_equal(m[t], s[t]) for t in m)
    stage = Usd.Stage.Open(str(example))
    src = stage.GetPrimAtPath(ANIM).GetAttribute("rotations")
    for t in src.GetTimeSamples():  # the keys, bitwise
        assert np.array_equal(s[t], np.array(src.Get(t)))


def test_other_actors_shot_records_its_decision(tmp_path):
    """A CMU take on a Character Creator rig (other actors, rig and capture): whatever the
    probes decide, it is recorded with its evidence."""
    shot = cmu_shot(tmp_path / "cc.usda", frames=121, keys_every=12)
    res = fill_shot(str(shot), FillOptions(out_dir=str(tmp_path / "o")))
    (d,) = res["trust"].values()
    assert d["choice"] in ("model", "blend", "spline") and len(d["probes"]) >= 1


def test_interpolation_and_rig_models_decide_nothing(example, tmp_path):
    res = fill_shot(str(example), FillOptions(out_dir=str(tmp_path / "i"), model="interp"))
    assert res["trust"] == {ANIM: None}


def test_bad_trust_is_one_line(example, tmp_path):
    with pytest.raises(TweenError, match=r"--trust 'maybe': must be one of auto, model, spline"):
        fill_shot(str(example), FillOptions(out_dir=str(tmp_path / "x"), trust="maybe"))
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "fill-local", str(example), "--trust", "maybe",
                        "--out", str(tmp_path / "y")], capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 2 and r.stdout == "" and len(r.stderr.strip().splitlines()) == 1
    assert "--trust" in r.stderr and not (tmp_path / "y").exists()
