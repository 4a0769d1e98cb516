"""The spline baseline: a clamped-tangent cubic through the keys, per channel."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.interpolate import CubicHermiteSpline, PchipInterpolator

from pipeline.bench.methods import BASELINES, interpolation, resolve
from pipeline.data.skeletons import bandai_skeleton
from pipeline.infer.api import Inbetweener, load_inbetweener
from pipeline.infer.spline import SplineInbetweener, spline_keys
from pipeline.motion.clip import Motion
from pipeline.motion.rotations import quat_mul, quat_normalize, slerp
from pipeline.motion.skeleton import Skeleton


def axis_angle(axis, angle):
    """(T, 4) xyzw quaternions about ``axis`` at ``angle`` (T,) radians."""
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    a = np.asarray(angle, np.float64)[:, None]
    return np.concatenate([np.sin(a / 2) * axis, np.cos(a / 2)], axis=-1)


def random_motion(rng, T, J):
    rot = quat_normalize(rng.normal(size=(T, J, 4))).astype(np.float32)
    root = rng.normal(size=(T, 3)).astype(np.float32) * 10
    return rot, root


def chain(J):
    return Skeleton(tuple(f"j{i}" for i in range(J)), np.arange(J) - 1, np.ones((J, 3), np.float32))


def rotation_angle(a, b):
    """Angle (rad) between unit quaternions, sign-blind."""
    return 2 * np.arccos(np.clip(np.abs((a * b).sum(-1)), 0, 1))


def test_keys_bitwise_exact_and_held_outside():
    rng = np.random.default_rng(0)
    rot, root = random_motion(rng, 40, 5)
    keys = np.array([3, 4, 11, 20, 33])
    r, p = spline_keys(rot, root, keys)
    assert r.dtype == np.float32 and p.dtype == np.float32
    assert r.shape == rot.shape and p.shape == root.shape
    # Random keys flip hemisphere often: the copies must still be the input's own bits.
    assert np.array_equal(r[keys].view(np.uint32), rot[keys].view(np.uint32))
    assert np.array_equal(p[keys].view(np.uint32), root[keys].view(np.uint32))
    assert (r[:3] == rot[3]).all() and (p[:3] == root[3]).all()
    assert (r[34:] == rot[33]).all() and (p[34:] == root[33]).all()
    between = np.setdiff1d(np.arange(3, 34), keys)
    assert not np.allclose(r[between], 0)  # the in-betweens were computed, not left empty


def test_root_lines_and_cubics():
    """PCHIP reproduces a straight line exactly and never overshoots a monotone track (a
    cubic rises and falls past its keys only where a C2 spline would ring); the not-a-knot
    C2 option reproduces a cubic exactly."""
    t = np.arange(61, dtype=np.float64)
    keys = np.array([0, 7, 12, 30, 41, 60])
    rot = np.tile(np.array([0, 0, 0, 1.0]), (61, 1, 1))
    line = np.stack([2.0 * t - 5, -0.5 * t, 3.0 + 0 * t], -1)
    _, p = spline_keys(rot, line, keys)
    np.testing.assert_allclose(p, line, atol=1e-9)

    cubic = np.stack([0.01 * t**3 - 0.3 * t**2 + 2 * t + 1, 0.002 * t**3, -(t**3) / 500 + t], -1)
    _, p_c2 = spline_keys(rot, cubic, keys, method="cubic")
    np.testing.assert_allclose(p_c2, cubic, atol=1e-8)
    _, p = spline_keys(rot, cubic, keys)
    assert np.abs(p - cubic).max() > 1e-3  # PCHIP is not C2: it does not reproduce cubics
    # Monotone channel (y = 0.002 t³): PCHIP stays monotone, inside each segment's key values.
    assert (np.diff(p[:, 1]) >= 0).all()
    for a, b in zip(keys[:-1], keys[1:], strict=True):
        seg = p[a : b + 1]
        lo = np.minimum(cubic[a], cubic[b]) - 1e-9
        hi = np.maximum(cubic[a], cubic[b]) + 1e-9
        assert ((seg >= lo) & (seg <= hi)).all()


def test_two_keys_are_linear_and_near_slerp():
    rng = np.random.default_rng(1)
    T = 31
    q0 = axis_angle([0, 1, 0], [0.0])[0]
    q1 = axis_angle([1, 2, 0], [1.2])[0]  # 69°
    rot = np.zeros((T, 3, 4))
    rot[0], rot[-1] = q0, q1
    root = rng.normal(size=(T, 3))
    r, p = spline_keys(rot, root, [0, T - 1])
    w = np.linspace(0, 1, T)
    np.testing.assert_allclose(p, (1 - w)[:, None] * root[0] + w[:, None] * root[-1], atol=1e-12)
    ref = slerp(q0, q1, w)  # (T, 4)
    # Normalised LERP of the components: within a degree of SLERP at 69°, on the same arc.
    assert rotation_angle(r[:, 0], ref).max() < np.radians(1.0)
    assert rotation_angle(r[:, 0], ref)[1:-1].max() > 1e-6  # not SLERP bit for bit, though
    # Ends: with flat end tangents the two-key curve eases in and out instead (Blender's default).
    _, p_flat = spline_keys(rot, root, [0, T - 1], ends="flat")
    s = 3 * w**2 - 2 * w**3
    np.testing.assert_allclose(p_flat, (1 - s)[:, None] * root[0] + s[:, None] * root[-1], atol=1e-12)


def test_quaternions_unit_and_sign_consistent_through_flipped_keys():
    """A rotation about one axis whose keys alternate between q and -q: the spline must follow
    the rotation smoothly, not the components through zero."""
    T = 49
    angle = np.linspace(0, 2.5, T)  # steady turn, 143°
    truth = axis_angle([0.3, 1, 0.2], angle)
    keys = np.arange(0, T, 8)
    rot = truth.copy()
    rot[keys[1::2]] *= -1  # every other key on the other hemisphere
    rot = rot[:, None].repeat(2, 1)
    r, _ = spline_keys(rot, np.zeros((T, 3)), keys)
    np.testing.assert_allclose(np.linalg.norm(r, axis=-1), 1, atol=1e-12)
    err = rotation_angle(r[:, 0], truth)
    assert err.max() < np.radians(0.5)
    # Between key k and k+1 the signs follow key k's, so no frame jumps except into a flipped key.
    step = (r[1:, 0] * r[:-1, 0]).sum(-1)
    into_flip = np.isin(np.arange(1, T), keys[1:])
    assert (step[~into_flip] > 0.99).all()
    # Without the hemisphere step the raw components' curve would be far off the rotation.
    naive = PchipInterpolator(keys, rot[keys, 0], axis=0)(np.arange(T))
    assert rotation_angle(quat_normalize(naive), truth).max() > np.radians(20)


def test_fill_on_a_100_joint_rig_and_the_protocol():
    rng = np.random.default_rng(2)
    skel = chain(100)
    rot, root = random_motion(rng, 50, 100)
    # Smooth-ish motion: small per-joint turns composed over time.
    delta = quat_normalize(np.r_[[[0, 0, 0, 1.0]]] + 0.05 * rng.normal(size=(50, 100, 4)))
    for t in range(1, 50):
        rot[t] = quat_mul(rot[t - 1], delta[t])
    motion = Motion(skel, rot, root, 24.0, "shot")
    keys = np.array([0, 9, 25, 49])
    sp = SplineInbetweener(skel)
    assert isinstance(sp, Inbetweener) and (sp.name, sp.model_hash, sp.fps) == ("spline", "none", 30.0)
    out = sp.fill(motion, keys, seed=3)
    assert out.skeleton is skel and out.fps == 24.0 and out.rotations.shape == (50, 100, 4)
    assert np.array_equal(out.rotations[keys], rot[keys])
    assert np.array_equal(out.root_positions[keys], root[keys])
    np.testing.assert_allclose(np.linalg.norm(out.rotations, axis=-1), 1, atol=1e-6)
    # The loader's spline is this one.
    loaded = load_inbetweener("spline")
    assert isinstance(loaded, SplineInbetweener) and len(loaded.skeleton) == len(bandai_skeleton())
    # fill_batch of N copies = N fills
    r, p = sp.fill_batch(np.stack([rot, rot[::-1]]), np.stack([root, root[::-1]]), keys)
    np.testing.assert_allclose(r[0], out.rotations, atol=1e-7)
    np.testing.assert_allclose(p[0], out.root_positions, atol=1e-6)
    with pytest.raises(ValueError, match="two keys"):
        sp.fill(motion, [5])


def test_bench_method_shapes_and_context_keys():
    rng = np.random.default_rng(3)
    n, c, J, T = 4, 10, 22, 15
    rot, root = random_motion(rng, n * (c + T + 1), J)
    rot = rot.reshape(n, c + T + 1, J, 4)
    root = root.reshape(n, c + T + 1, 3)
    method = resolve("spline")
    assert method is BASELINES["spline"]
    p_rot, p_root = method(rot[:, :c], root[:, :c], rot[:, -1], root[:, -1], T)
    assert p_rot.shape == (n, T, J, 4) and p_root.shape == (n, T, 3)
    assert p_rot.dtype == np.float32 and p_root.dtype == np.float32
    # Context frames are keys: a root moving at constant velocity through the context and on to
    # the target is continued exactly, where interpolation from the last frame would be too.
    t = np.arange(c + T + 1, dtype=np.float32)
    lin = np.stack([3 * t, 0 * t, -t], -1)[None].repeat(n, 0)
    _, p_root = method(rot[:, :c], lin[:, :c], rot[:, -1], lin[:, -1], T)
    np.testing.assert_allclose(p_root, lin[:, c : c + T], atol=1e-4)
    # A quadratic in time (accelerating root): the spline, reading the context's curve, beats LERP.
    quad = np.stack([0.1 * t**2, 0 * t, 0 * t], -1)[None].repeat(n, 0)
    _, p_sp = method(rot[:, :c], quad[:, :c], rot[:, -1], quad[:, -1], T)
    _, p_lin = interpolation(rot[:, :c], quad[:, :c], rot[:, -1], quad[:, -1], T)
    truth = quad[:, c : c + T]
    assert np.abs(p_sp - truth).mean() < 0.5 * np.abs(p_lin - truth).mean()


def _root_only(T):
    """Identity rotations of one joint over T frames (the root channel carries the test)."""
    rot = np.zeros((T, 1, 4), np.float64)
    rot[..., 3] = 1.0
    return rot


def test_adaptive_takes_catmull_rom_slopes_at_dense_keys_and_pchip_at_sparse():
    from pipeline.infer.spline import DENSE_S, SPARSE_S

    T = 121
    t = np.arange(T, dtype=np.float64)
    root = np.stack([np.sin(t / 7.0) * 50, np.cos(t / 11.0) * 20, t * 0.3], axis=1)
    rot = _root_only(T)
    for every, fps in ((10, 30.0), (30, 30.0), (10, 12.0)):
        keys = np.arange(0, T, every)
        _, adaptive = spline_keys(rot, root, keys, "adaptive", fps=fps)
        _, pchip = spline_keys(rot, root, keys, "pchip", fps=fps)
        assert np.array_equal(adaptive[keys], root[keys])  # keys bitwise
        gap_s = every / fps
        # The curve its definition gives: Catmull-Rom's slope at every interior key (within
        # Fritsch-Carlson's bound), PCHIP's one-sided slope at the two ends.
        slopes = PchipInterpolator(keys, root[keys], axis=0).derivative()(keys)
        secant = np.abs(np.diff(root[keys], axis=0)) / every
        bound = 3 * np.minimum(secant[:-1], secant[1:])
        slopes[1:-1] = np.clip((root[keys[2:]] - root[keys[:-2]]) / (2 * every), -bound, bound)
        catmull = CubicHermiteSpline(keys, root[keys], slopes, axis=0)(t[: keys[-1] + 1])
        if gap_s <= DENSE_S:
            assert np.allclose(adaptive[: keys[-1] + 1], catmull, atol=1e-9)
            assert not np.allclose(adaptive, pchip, atol=1e-2)
        elif gap_s >= SPARSE_S:  # every 30 at 30 fps, and every 10 frames at 12 fps
            assert np.allclose(adaptive, pchip, atol=1e-9)


def test_adaptive_is_closer_than_pchip_to_smooth_motion_keyed_densely_and_no_worse_sparsely():
    # A smooth motion keyed every 10 frames: clamped tangents flatten every key where a
    # channel turns; the adaptive curve follows it (what it is for).
    T = 301
    t = np.arange(T, dtype=np.float64)
    root = np.stack([np.sin(t / 9.0) * 40 + np.sin(t / 23.0) * 25, np.cos(t / 13.0) * 15, t], axis=1)
    rot = _root_only(T)
    for every, better in ((10, True), (30, False)):
        keys = np.r_[np.arange(0, T - 1, every), T - 1]
        err = {
            m: np.abs(spline_keys(rot, root, keys, m)[1] - root)[:, :2].mean() for m in ("pchip", "adaptive")
        }
        if better:
            assert err["adaptive"] < 0.7 * err["pchip"]
        else:
            assert err["adaptive"] <= err["pchip"] * (1 + 1e-9)


def test_adaptive_does_not_overshoot_into_a_hold():
    """A fast rise keyed every 10 frames, then a hold (the arm raised and kept there, with
    capture jitter): Catmull-Rom's slope at the hold's first key is half the rise's pace and
    swings past the hold; within Fritsch-Carlson's bound it stays at the hold, as PCHIP does."""
    T = 61
    root = np.zeros((T, 3))
    root[:31, 1] = np.linspace(0, 90, 31)
    root[31:, 1] = 90 + 0.05 * np.sin(np.arange(30))  # the hold, jittering by a millimetre
    rot = _root_only(T)
    keys = np.arange(0, T, 10)
    _, got = spline_keys(rot, root, keys, "adaptive")
    with_hold = got[31:40, 1]
    assert with_hold.max() < 90.5 and with_hold.min() > 89.5
    unbounded = (root[40, 1] - root[20, 1]) / 20  # what Catmull-Rom's slope at frame 30 would be
    assert unbounded > 1.0  # a swing of centimetres a frame past the hold, without the bound


def test_adaptive_keeps_pchip_slopes_beside_a_cut():
    # Keys every 10 frames, the body teleporting 6 m between frames 30 and 40: the keys beside
    # the cut keep PCHIP's slope (across the cut the animator's spline, as before the curve).
    T = 81
    root = np.zeros((T, 3))
    root[:, 0] = np.linspace(0, 40, T)
    root[40:, 0] += 600.0
    root[:, 1] = 20 * np.sin(np.arange(T) / 5.0)  # a sway, where the two rules differ
    rot = _root_only(T)
    keys = np.arange(0, T, 10)
    _, free = spline_keys(rot, root, keys, "adaptive")
    _, cut = spline_keys(rot, root, keys, "adaptive", breaks=[(30, 40)])
    _, pchip = spline_keys(rot, root, keys, "pchip")
    gap = slice(21, 30)  # the gap before the cut: between its keys' 10 and 15 cm
    # Without the break the key's slope is Catmull-Rom's, held by Fritsch-Carlson's bound to 3x
    # the small secant beside it; with it, PCHIP's.
    assert not np.allclose(free[gap, 0], cut[gap, 0], atol=0.05)
    assert (cut[gap, 0] >= root[20, 0] - 1e-6).all() and (cut[gap, 0] <= root[30, 0] + 1e-6).all()
    assert np.allclose(cut[30:41], pchip[30:41], atol=1e-9)  # across the cut: both keys PCHIP's
    assert not np.allclose(cut[:11], pchip[:11], atol=1e-3)  # elsewhere still adaptive
    assert np.array_equal(cut[keys], root[keys])


def test_the_trusted_fill_checks_and_falls_back_on_the_adaptive_curve():
    from pipeline.infer import trust

    rng = np.random.default_rng(3)
    skel = bandai_skeleton()
    inb = trust.TrustedInbetweener(load_inbetweener("default"), trust="spline")
    assert inb.spline.method == trust.CURVE == "adaptive"
    rot, root = random_motion(rng, 61, len(skel.names))
    motion = Motion(skel, rot, root, 30.0, "shot")
    keys = np.arange(0, 61, 10)
    got = inb.fill(motion, keys)
    want = SplineInbetweener(skel, method="adaptive").fill(motion, keys)
    assert np.array_equal(got.rotations, want.rotations)
    assert not np.allclose(got.rotations, SplineInbetweener(skel).fill(motion, keys).rotations, atol=1e-4)


@settings(max_examples=60, deadline=None)
@given(
    data=st.data(),
    T=st.integers(2, 80),
    fps=st.sampled_from([12.0, 24.0, 30.0, 60.0, 120.0]),
)
def test_adaptive_keeps_keys_bitwise_and_unit_rotations_for_any_keys(data, T, fps):
    """Generated: any key layout (two keys, dense runs, lone far keys), any rate, any cuts."""
    keys = np.array(sorted(data.draw(st.sets(st.integers(0, T - 1), min_size=2, max_size=T))))
    seed = data.draw(st.integers(0, 2**31 - 1))
    rot, root = random_motion(np.random.default_rng(seed), T, 3)
    root[keys[len(keys) // 2] :] += data.draw(st.floats(-1e4, 1e4))  # a jump, perhaps a cut
    pairs = list(zip(keys[:-1].tolist(), keys[1:].tolist(), strict=True))
    breaks = data.draw(st.lists(st.sampled_from(pairs), max_size=3))
    r, p = spline_keys(rot, root, keys, "adaptive", fps=fps, breaks=breaks)
    assert np.array_equal(r[keys], rot[keys]) and np.array_equal(p[keys], root[keys])
    assert np.isfinite(r).all() and np.isfinite(p).all()
    assert np.allclose(np.linalg.norm(r, axis=-1), 1.0, atol=1e-5)
    # Outside the keys the first and last key are held, as every spline holds them.
    assert (r[: keys[0]] == rot[keys[0]]).all() and (p[keys[-1] + 1 :] == root[keys[-1]]).all()
