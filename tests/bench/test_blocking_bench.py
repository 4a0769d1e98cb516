"""The blocking bench (pipeline/bench/blocking.py): the trusted fill on shots keyed every N frames."""

import json

import numpy as np
import pytest

from pipeline.adapt.retarget import typical_local
from pipeline.bench import blocking
from pipeline.bench.heldout import posture_degrees
from pipeline.data.skeletons import bandai_skeleton
from pipeline.errors import TweenError
from pipeline.motion.fk import fk
from pipeline.motion.rotations import quat_normalize


def test_blocking_bench_runs_end_to_end_on_cmu_takes(tmp_path, capsys):
    assert blocking.main(["--sources", "cmu", "--every", "10", "--limit", "2", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "blocking.json").read_text())
    r = report["sources"]["cmu"]["results"]["10"]
    assert report["sources"]["cmu"]["shots"] >= 1 and r["probes"] >= 1
    for k in ("model", "spline", "decided"):
        assert r[k] > 0
    # The decided fill is a blend of the two, so it cannot be worse than the worse of them by much.
    assert r["decided"] <= 1.05 * max(r["model"], r["spline"])
    assert 0.0 <= r["mean_weight"] <= 1.0
    assert "| cmu | 10 |" in capsys.readouterr().out
    # The shipped library and delta network are probed beside the network as the fill probes
    # them (probed_beside), each with the share of shots it decided.
    library, *networks = report["beside"]
    assert "cmu-subjects-1-3" in library["name"] and library["hash"]
    assert [b["name"] for b in networks] == ["tween-bandai-delta-v3"]
    assert len(r["alternative_shares"]) == 2 and sum(r["alternative_shares"]) == pytest.approx(
        r["alternative_share"]
    )
    assert "| lib | tween-bandai-delta-v3 |" in report["markdown"]


def test_blocking_bench_without_the_library_probes_the_network_only(tmp_path):
    args = ["--sources", "cmu", "--every", "30", "--limit", "1", "--out", str(tmp_path), "--no-library"]
    assert blocking.main(args) == 0
    assert json.loads((tmp_path / "blocking.json").read_text())["beside"] == []


def test_too_short_clips_are_one_clear_error():
    with pytest.raises(TweenError, match="no clip longer than 181 frames"):
        blocking.shots("eval", limit=3)


def test_a_rig_without_a_joint_keeps_its_childrens_world_rotations():
    """``noshoulders`` / ``nospine``: the missing joint in the model's typical pose, the bones
    below it turned the same in the world; only the missing joint's own bone moves them."""
    skel = bandai_skeleton()
    rng = np.random.default_rng(3)
    rots = quat_normalize(rng.normal(size=(4, len(skel.names), 4)))
    roots = rng.normal(size=(4, 3))
    for name, joints in blocking.MISSING.items():
        out = blocking.without_joints(rots, joints)
        g0, p0 = fk(rots, roots, skel.parents, skel.offsets)
        g1, p1 = fk(out, roots, skel.parents, skel.offsets)
        g0, g1 = np.asarray(g0), np.asarray(g1)
        for j in joints:
            i = skel.index(j)
            assert np.allclose(out[:, i], typical_local()[i]), name
            kids = np.flatnonzero(np.asarray(skel.parents) == i)
            same = np.abs(np.sum(g0[:, kids] * g1[:, kids], axis=-1))
            assert np.allclose(same, 1.0, atol=1e-5), name  # the children's world rotations
            assert not np.allclose(p0[:, kids], p1[:, kids], atol=1e-3), name  # moved by its bone
        rest = [k for k in range(len(skel.names)) if skel.names[k] not in joints]
        assert not np.allclose(out[:, rest], rots[:, rest])  # the children were turned
    with pytest.raises(TweenError, match="postureN"):
        blocking.shots("nohands")


def test_posture_sources_take_any_angle():
    # One parser for the blocking and trust benches (pipeline.bench.heldout.posture_degrees).
    assert posture_degrees("posture10") == 10.0 and posture_degrees("posture30") == 30.0
    assert posture_degrees("eval") is None and posture_degrees("posturex") is None
