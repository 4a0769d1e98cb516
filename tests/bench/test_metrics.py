"""The protocol's metrics on hand-computed cases, the baselines and window normalisation."""

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.bench import metrics
from pipeline.bench.methods import interpolation, zero_velocity
from pipeline.data.protocol import facing, global_positions, normalize_windows, window_starts
from pipeline.data.skeletons import bandai_skeleton

RNG = np.random.default_rng(0)


def test_identical_motion_scores_zero():
    q = Rotation.random(2 * 5 * 21, random_state=0).as_quat().reshape(2, 5, 21, 4)
    p = RNG.normal(size=(2, 5, 21, 3))
    assert metrics.l2q(q, q) == 0
    assert metrics.l2p(p, p, np.zeros(63), np.ones(63)) == 0
    assert metrics.npss(q, q) == 0
    assert metrics.mpjpe(p, p) == 0


def test_constant_offset_known_values():
    p = RNG.normal(size=(3, 7, 21, 3))
    shifted = p + np.array([3.0, 0.0, 4.0])  # every joint 5 cm away
    assert np.isclose(metrics.mpjpe(shifted, p), 5.0)
    std = np.full(63, 2.0)
    # Per frame: 21 joints each contributing (1.5² + 2²) after dividing by std 2.
    assert np.isclose(metrics.l2p(shifted, p, np.zeros(63), std), np.sqrt(21 * (1.5**2 + 2**2)))
    q = np.zeros((3, 7, 21, 4))
    q2 = q.copy()
    q2[..., 3] = 0.1
    assert np.isclose(metrics.l2q(q2, q), 0.1 * np.sqrt(21))


def test_npss_sine_against_shifted_frequency():
    t = np.arange(32)

    def wave(k, amp=1.0):  # a sine of k cycles, phase-shifted so its FFT is real
        return (amp * np.sin(2 * np.pi * k * t / 32 + np.pi / 2))[None, :, None, None].repeat(4, -1)

    assert np.isclose(metrics.npss(wave(2, amp=3.0), wave(2)), 0, atol=1e-12)  # same spectrum shape
    # Power at bins {2, 30} vs {5, 27}: the CDFs differ by 0.5 over bins 2-4 and 27-29 = 3.0.
    assert np.isclose(metrics.npss(wave(5), wave(2)), 3.0)
    assert metrics.npss(wave(3), wave(2)) < metrics.npss(wave(5), wave(2))


def test_foot_skate_counts_only_true_contacts():
    T, J = 4, 2
    true = np.zeros((1, T, J, 3))
    true[0, :, 1, 0] = np.arange(1, T + 1) * 10.0  # joint 1 moves: never in contact
    pred = true.copy()
    pred[0, :, 0, 0] = np.arange(1, T + 1) * 0.5  # joint 0 slides 0.5 cm per frame
    prev = np.zeros((1, J, 3))
    skate, n = metrics.foot_skate(pred, true, prev, prev, [0, 1])
    assert n == T and np.isclose(skate, 0.5)
    skate_gt, _ = metrics.foot_skate(true, true, prev, prev, [0, 1])
    assert skate_gt == 0


def test_interpolation_hits_both_endpoints():
    q = Rotation.random(2 * 21 * 2, random_state=4).as_quat().reshape(2, 2, 21, 4)
    ctx = np.repeat(q[:, :1], 10, axis=1)
    roots = RNG.normal(size=(2, 2, 3))
    T = 15
    rot, root = interpolation(ctx, np.repeat(roots[:, :1], 10, 1), q[:, 1], roots[:, 1], T)
    assert rot.shape == (2, T, 21, 4) and root.shape == (2, T, 3)
    # Extending the weights to 0 and 1 gives exactly the two key poses.
    full_w = np.linspace(0, 1, T + 2)
    step = full_w[1]
    np.testing.assert_allclose(root[:, 0], roots[:, 0] + step * (roots[:, 1] - roots[:, 0]), atol=1e-5)
    np.testing.assert_allclose(root[:, -1], roots[:, 1] - step * (roots[:, 1] - roots[:, 0]), atol=1e-5)
    from pipeline.motion.rotations import slerp

    ends = slerp(q[:, 0], q[:, 1], np.array([0.0, 1.0]))
    np.testing.assert_allclose(np.abs((ends[0] * q[:, 0]).sum(-1)), 1, atol=1e-6)
    np.testing.assert_allclose(np.abs((ends[1] * q[:, 1]).sum(-1)), 1, atol=1e-6)
    zr, zp = zero_velocity(ctx, np.repeat(roots[:, :1], 10, 1), q[:, 1], roots[:, 1], 5)
    assert (zr == ctx[:, -1:]).all() and zr.shape[1] == 5


def test_window_rule():
    assert list(window_starts(65, 65, 40)) == []
    assert list(window_starts(66, 65, 40)) == [0]
    assert list(window_starts(145, 65, 40)) == [0, 40]
    assert list(window_starts(146, 65, 40)) == [0, 40, 80]


def test_normalised_windows_face_plus_x_and_are_centred(bandai_clip):
    from pipeline.motion.bvh import read_bvh

    m = read_bvh(bandai_clip).continuous()
    rots, roots = m.rotations[None, :65], m.root_positions[None, :65]
    nr, npos = normalize_windows(rots, roots)
    np.testing.assert_allclose(npos[0, :, [0, 2]].mean(axis=1), 0, atol=1e-3)
    _, pos = global_positions(nr[:, 9], npos[:, 9])
    np.testing.assert_allclose(facing(pos, bandai_skeleton())[0], [1, 0, 0], atol=1e-5)
    # Body shape unchanged: distances between joints are rotation/translation invariant.
    _, before = global_positions(rots[:, 30], roots[:, 30])
    _, after = global_positions(nr[:, 30], npos[:, 30])
    d0 = np.linalg.norm(before[0, :, None] - before[0, None], axis=-1)
    d1 = np.linalg.norm(after[0, :, None] - after[0, None], axis=-1)
    np.testing.assert_allclose(d0, d1, atol=1e-3)
