"""One fill path: a shot the benchmark fills is, bit for bit, the shot ``tween fill-local`` fills."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from usd_fixtures import BANDAI_CLIP

from pipeline.bench import rig_variants as rv
from pipeline.cli import main
from pipeline.motion.augment import posture_offsets
from pipeline.motion.bvh import read_bvh


def _samples(layer_path: str) -> dict:
    """{attribute path: {time: value array}} of every time-sampled attribute of a layer."""
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(layer_path)
    out = {}

    def visit(path):
        if path.IsPropertyPath() and layer.GetNumTimeSamplesForPath(path):
            out[str(path)] = {
                t: np.asarray(layer.QueryTimeSample(path, t)) for t in layer.ListTimeSamplesForPath(path)
            }

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return out


def test_the_bench_entry_and_fill_local_fill_a_shot_bit_for_bit(tmp_path, capsys):
    # A walk on a rig posed up to 30° off the actors', keyed every 30 frames: the trusted fill
    # decides for a blend (weight about a third; the delta network shipped beside it does no
    # better at the probes), so the network's and the spline's fills both reach the rig and
    # meet there. (Keyed every 20 the delta network fills it alone.)
    clip = read_bvh(BANDAI_CLIP).slice(0, 81)
    rot = posture_offsets(clip.rotations[None], np.random.default_rng(0), 30.0, 1.0)[0]
    clip = replace(clip, rotations=rot)
    shot = rv.write_rig_shot(rv.model_rig_of(clip), tmp_path / "shot.usda", keys_every=30)
    review = rv.fill_review(shot, "default", tmp_path / "bench")
    capsys.readouterr()
    with pytest.raises(SystemExit) as done:
        main(["fill-local", str(shot), "--out-dir", str(tmp_path / "cli")])
    assert done.value.code == 0
    res = json.loads(capsys.readouterr().out)
    assert 0.2 < next(iter(res["trust"].values()))["weight"] < 0.8
    bench_layer = Path(review).parent / Path(res["layer"]).name
    a, b = _samples(str(bench_layer)), _samples(res["layer"])
    assert a.keys() == b.keys() and any(k.endswith(".rotations") for k in a)
    for attr, samples in a.items():
        assert samples.keys() == b[attr].keys(), attr
        for t, v in samples.items():
            assert v.dtype == b[attr][t].dtype and np.array_equal(v, b[attr][t]), (attr, t)
