"""Fill speed (issue 20 item 5): batched numpy rotations and FK equal scipy's, post-processing
equals its scipy-based form, the adapter-free generator equals the whole graph on full keys,
and ``tween bench --speed`` prints its table."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import pipeline.infer.post as post
from pipeline.data.skeletons import bandai_skeleton
from pipeline.infer.features import AdapterFreeSession, adapter_free_graph, build_features
from pipeline.infer.generator_onnx import OnnxInbetweener
from pipeline.motion import rotations as R
from pipeline.motion.bvh import read_bvh
from pipeline.motion.fk import fk

SKEL = bandai_skeleton()
J = len(SKEL)
RNG = np.random.default_rng(20)


def _unit(n):
    q = RNG.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def scipy_fk(local_rot, root_pos, parents, offsets):
    """The FK of before: one scipy Rotation product and application per joint."""
    g_rot, g_pos = [None] * len(parents), [None] * len(parents)
    for j, p in enumerate(parents):
        if p < 0:
            g_rot[j] = np.asarray(local_rot[..., j, :], np.float64)
            g_pos[j] = np.asarray(root_pos, np.float64)
        else:
            g_rot[j] = R.quat_mul(g_rot[p], local_rot[..., j, :].astype(np.float64))
            g_pos[j] = g_pos[p] + R.quat_apply(g_rot[p], np.asarray(offsets[j], np.float64))
    return np.stack(g_rot, -2), np.stack(g_pos, -2)


def test_batched_rotation_helpers_equal_scipy():
    q, p, v = _unit(4000), _unit(4000), RNG.normal(size=(4000, 3))
    assert (
        np.abs(R.batch_quat_mul(q, p) - (Rotation.from_quat(q) * Rotation.from_quat(p)).as_quat()).max()
        < 1e-12
    )
    assert np.abs(R.batch_quat_apply(q, v) - Rotation.from_quat(q).apply(v)).max() < 1e-12
    assert np.abs(R.batch_quat_to_rotvec(q) - Rotation.from_quat(q).as_rotvec()).max() < 1e-12
    tiny = q.copy()
    tiny[:, :3] *= 1e-6  # the small-angle series
    tiny /= np.linalg.norm(tiny, axis=-1, keepdims=True)
    assert np.abs(R.batch_quat_to_rotvec(tiny) - Rotation.from_quat(tiny).as_rotvec()).max() < 1e-12
    rv = RNG.normal(size=(4000, 3)) * np.exp(RNG.uniform(-14, 1, size=(4000, 1)))
    assert np.abs(R.batch_rotvec_to_quat(rv) - Rotation.from_rotvec(rv).as_quat()).max() < 1e-12
    assert np.abs(R.batch_quat_to_matrix(3 * q) - Rotation.from_quat(q).as_matrix()).max() < 1e-12
    m = Rotation.from_quat(q).as_matrix()
    assert np.abs(R.batch_matrix_to_quat(m) - Rotation.from_matrix(m).as_quat()).max() < 1e-12
    assert np.abs(R.batch_quat_to_6d(q) - R.quat_to_6d(q)).max() < 1e-12
    # Broadcasting as the scipy-based helpers do.
    assert np.abs(R.batch_quat_mul(q[:1], p) - R.quat_mul(q[:1], p)).max() < 1e-12
    assert np.abs(R.batch_quat_apply(q, v[0]) - R.quat_apply(q, v[0])).max() < 1e-12


def _slerp_reference(q0, q1, w, lerp_eps=0.01):
    """SLERP with numpy's own reductions (what slerp_pairs computed before it summed by hand)."""
    w = np.asarray(w, np.float64)[..., None]
    dot = (q0 * q1).sum(-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    near = (1.0 - dot) < lerp_eps
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_t = np.where(near, 1.0, np.sin(theta))
    s0 = np.where(near, 1.0 - w, np.sin((1.0 - w) * theta) / sin_t)
    s1 = np.where(near, w, np.sin(w * theta) / sin_t)
    out = s0 * q0 + s1 * q1
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def test_slerp_and_continuity_are_bitwise_the_loops():
    a, b = RNG.normal(size=(2, 300, J, 4)), RNG.normal(size=(2, 300, J, 4))
    b[0, :40] = a[0, :40] * 1.001  # the LERP branch
    w = RNG.uniform(size=(1, 300, 1))
    assert np.array_equal(R.slerp_pairs(a, b, w), _slerp_reference(a, b, w))
    x = RNG.normal(size=(2, 300, J, 4))
    x[0, 100] = 0.0  # a zero dot restarts the loop's flips
    for axis in (0, 1):
        assert np.array_equal(R.batch_quat_continuity(x, axis), R.quat_continuity(x, axis))


def test_fk_equals_the_scipy_chain():
    q = RNG.normal(size=(3, 50, J, 4)).astype(np.float32)  # not unit: scipy normalised them
    root = RNG.normal(size=(3, 50, 3)).astype(np.float32) * 100
    gq, gp = fk(q, root, SKEL.parents, SKEL.offsets)
    rq, rp = scipy_fk(q, root, SKEL.parents, SKEL.offsets)
    assert gq.dtype == np.float32 and gp.dtype == np.float32
    assert np.abs(gq - rq).max() < 1e-6 and np.abs(gp - rp).max() < 1e-4  # float32 outputs
    gq, gp = fk(q.astype(np.float64), root.astype(np.float64), SKEL.parents, SKEL.offsets)
    assert np.abs(gq - rq).max() < 1e-12 and np.abs(gp - rp).max() < 1e-10  # positions in cm
    feet = [SKEL.index("Foot_L"), SKEL.index("Foot_R")]
    sq, sp = fk(q.astype(np.float64), root.astype(np.float64), SKEL.parents, SKEL.offsets, joints=feet)
    done = ~np.isnan(sq[0, 0, :, 0])
    assert done[feet].all() and done.sum() == 7  # the feet and their ancestors only
    assert np.array_equal(sq[..., done, :], gq[..., done, :]) and np.array_equal(
        sp[..., done, :], gp[..., done, :]
    )


@pytest.fixture(scope="module")
def clip(bandai_clip):
    m = read_bvh(bandai_clip).continuous()
    return m.rotations[None, :150].astype(np.float32), m.root_positions[None, :150].astype(np.float32)


@pytest.fixture(scope="module")
def model():
    return OnnxInbetweener("models/default")


def test_post_processing_equals_its_scipy_form(clip, model, monkeypatch):
    """match_keys and lock_feet on the network's output, against the same code run with the
    scipy-based helpers and FK of before."""
    rot, root = clip
    keys = np.r_[np.arange(0, 149, 10), 149]
    q, r, contacts = model.raw(rot, root, keys)

    def run():
        mq, mr = post.match_keys(q, r, rot[:, keys], root[:, keys], keys)
        mask = np.ones((len(keys), J + 1), bool)
        mask[3, :] = False
        mask[3, J] = True  # a root-only key
        pq, pr = post.match_keys(q, r, rot[:, keys], root[:, keys], keys, mask)
        feet = post.lock_feet(
            mq[0], mr[0], SKEL, contacts[0][:, [0, 2]], keys, model.legs, anchor=True, orient=True
        )
        plain = post.lock_feet(mq[0], mr[0], SKEL, contacts[0][:, [0, 2]], keys, model.legs)
        return mq, mr, pq, pr, feet, plain

    new = run()

    def scipy_rotvec(q):
        return Rotation.from_quat(q.reshape(-1, 4)).as_rotvec().reshape(q.shape[:-1] + (3,))

    def scipy_from_rotvec(v):
        return Rotation.from_rotvec(v.reshape(-1, 3)).as_quat().reshape(v.shape[:-1] + (4,))

    for name, fn in {
        "batch_quat_mul": R.quat_mul,
        "batch_quat_apply": R.quat_apply,
        "batch_quat_to_rotvec": scipy_rotvec,
        "batch_rotvec_to_quat": scipy_from_rotvec,
        "batch_quat_continuity": lambda q, axis=0, copy=True: R.quat_continuity(q, axis),
        "fk": lambda q, r, parents, offsets, joints=None: scipy_fk(q, r, parents, offsets),
    }.items():
        monkeypatch.setattr(post, name, fn)
    old = run()
    assert any(
        np.abs(a - b).max() > 0 for a, b in zip(new[4:], (new[0][0], new[0][0]), strict=True)
    )  # feet moved
    for a, b in zip(new, old, strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype
        assert np.abs(a.astype(np.float64) - b).max() < 1e-5


def test_adapter_free_generator_equals_the_whole_graph(clip):
    rot, root = clip
    keys = np.r_[np.arange(0, 149, 8), 149]
    lean, whole = OnnxInbetweener("models/default"), OnnxInbetweener("models/default")
    whole.skip_adapter = False
    if adapter_free_graph(lean.folder / "generator.onnx", J) is None:
        pytest.skip("no onnx package: fills run the whole graph")
    assert isinstance(lean.session("generator"), AdapterFreeSession)
    assert not isinstance(whole.session("generator"), AdapterFreeSession)
    noise = np.random.default_rng(1).normal(size=(1, 8))
    for args in ((keys,), (keys, noise)):
        a, b = lean.fill_batch(rot, root, *args), whole.fill_batch(rot, root, *args)
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert lean.session("generator").lean is not None  # it ran the adapter-free graph
    # Partial keys still go through the whole graph and its adapter.
    mask = np.ones((len(keys), J + 1), bool)
    mask[4, :J] = False
    a, b = lean.fill_batch(rot, root, keys, None, mask), whole.fill_batch(rot, root, keys, None, mask)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    # The features without the side input are the whole graph's first channels.
    feats, _ = build_features(rot[:, :64], root[:, :64], np.array([0, 30, 63]), SKEL, key_adapter=True)
    lean_feats, _ = build_features(
        rot[:, :64], root[:, :64], np.array([0, 30, 63]), SKEL, key_adapter=True, adapter=False
    )
    assert (
        np.array_equal(feats[:, : lean_feats.shape[1]], lean_feats)
        and not feats[:, lean_feats.shape[1] :].any()
    )


def test_bench_speed_prints_its_table(tmp_path):
    env = dict(os.environ, TWEEN_SPEED_FRAMES="160", TWEEN_SPEED_REPEATS="1")
    res = subprocess.run(
        [sys.executable, "-m", "pipeline.cli", "bench", "--speed", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=240,
        env=env,
    )
    assert res.returncode == 0, res.stderr
    assert (
        "sgemm peak" in res.stdout
        and "| path | MFLOP/frame |" in res.stdout
        and "ORT_ENABLE_ALL" in res.stdout
    )
    rep = json.loads((tmp_path / "speed.json").read_text())
    assert rep["frames"] == 160 and rep["sgemm_peak"]["gflops"] > 0
    assert rep["shipped_vs_whole_graph"]["max_abs_diff"] == 0.0
    fl = rep["generator_flops_per_frame"]
    if fl["source"] == "ONNX graph":  # the model card's count, from the torch modules
        assert fl["total"] == 1707392.0 and fl["total"] - fl["adapter"] == pytest.approx(1.41e6, rel=0.01)


def test_a_root_only_key_leaves_the_joints_as_without_it(clip, model):
    """match_keys' blocked correction: a key of the root only spreads nothing on the joints
    (their rotations are those of the same keys without it), whatever memory it reuses."""
    rot, root = clip
    keys = np.r_[np.arange(0, 149, 10), 149]
    q, r, _ = model.raw(rot, root, keys)
    mask = np.ones((len(keys), J + 1), bool)
    mask[3, :J] = False
    keep = np.arange(len(keys)) != 3
    for _ in range(2):
        mq, _ = post.match_keys(q, r, rot[:, keys], root[:, keys], keys, mask)
        wq, _ = post.match_keys(q, r, rot[:, keys[keep]], root[:, keys[keep]], keys[keep])
        assert np.array_equal(mq, wq)


def test_blocked_and_per_pair_forms_are_bitwise_the_whole_array_forms():
    """The blocks (rotations.BLOCK), the per-gap SLERP terms and the TTA sinusoids per
    distinct distance change no bit."""
    from pipeline.infer.features import _tta, key_neighbours, tta_embedding

    q = RNG.normal(size=(1, 3000, J, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    keys = np.r_[np.arange(0, 2999, 7), 2999]
    prev, nxt = key_neighbours(3000, keys)
    w = np.where(nxt > prev, (np.arange(3000) - prev) / np.maximum(nxt - prev, 1), 0.0)
    assert np.array_equal(
        R.slerp_frames(q, prev, nxt, w), _slerp_reference(q[:, prev], q[:, nxt], w[None, :, None])
    )
    d6 = R.batch_quat_to_6d(q)
    assert np.abs(d6 - R.quat_to_6d(q.reshape(-1, 4)).reshape(d6.shape)).max() < 1e-12
    via_matrix = R.batch_matrix_to_quat(R.batch_sixd_to_matrix(d6))
    assert np.array_equal(R.batch_sixd_to_quat(d6), via_matrix)
    channels = np.ascontiguousarray(np.moveaxis(d6, -1, 2))  # (1, N, 6, J): another layout
    assert np.array_equal(R.batch_sixd_to_quat(channels, axis=2), via_matrix)
    assert np.array_equal(
        R.batch_quat_mul(q, q[:, ::-1])[:, :100], R.batch_quat_mul(q[:, :100], q[:, ::-1][:, :100])
    )
    dist = (np.arange(4096) - key_neighbours(4096, np.r_[np.arange(0, 4095, 10), 4095])[0]).astype(np.float64)
    assert np.array_equal(tta_embedding(dist), _tta(dist))
