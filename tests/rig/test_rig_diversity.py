"""GANimator's coverage / global (PNN) / local diversity on sequences with known answers,
and the diagonal-prefix DP against the paper's brute-force O(L_Q²·L_T) recursion."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.motion.rotations import euler_to_quat
from pipeline.rig import diversity


def _clip(T=120, J=8, seed=0):
    """A smooth, non-repeating rotation clip (T, J, 4)."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None, None]
    freq = rng.uniform(0.05, 0.2, (1, J, 3))
    phase = rng.uniform(0, 2 * np.pi, (1, J, 3))
    amp = rng.uniform(30, 90, (1, J, 3))
    ang = amp * np.sin(freq * t + phase) + 0.3 * t  # a drift makes every window unique
    return euler_to_quat(ang.reshape(-1, 3), "XYZ").reshape(T, J, 4)


def _brute_pnn(c: np.ndarray, t_min: int) -> float:
    """Appendix B as written: D(i) = min_{j ≤ i−T_min, k} D(j) + Σ_m C[j+m, k+m]."""
    lq, lt = c.shape
    d = np.full(lq + 1, np.inf)
    d[0] = 0
    for i in range(t_min, lq + 1):
        for j in range(0, i - t_min + 1):
            if not np.isfinite(d[j]):
                continue
            n = i - j
            for k in range(0, lt - n + 1):
                d[i] = min(d[i], d[j] + sum(c[j + m, k + m] for m in range(n)))
    return d[lq] / lq


def test_sample_equal_to_source():
    src = diversity.features(_clip())
    assert diversity.coverage(src, src) == 1.0
    assert diversity.local_diversity(src, src) == 0.0
    pnn = diversity.global_diversity(src, src)
    assert pnn.value == 0.0
    assert pnn.segments == [(0, 120, 0)] and np.array_equal(pnn.labels, np.arange(120))
    # The paper's squared cost says the same.
    assert diversity.coverage(src, src, mode="paper", eps=1e-6) == 1.0


def test_constant_sample_has_low_coverage():
    q = _clip()
    src = diversity.features(q)
    static = diversity.features(np.repeat(q[60:61], 240, axis=0))
    cov = diversity.coverage(static, src)
    assert cov < 0.2, cov
    assert diversity.local_diversity(static, src) > 0  # a pose that is in the clip only once
    # A sample that wanders away from the clip entirely covers nothing and is "diverse".
    other = diversity.features(_clip(seed=5))
    assert diversity.coverage(other, src) == 0.0
    assert diversity.global_diversity(other, src).value > 1.0


def test_reordered_halves_keep_zero_pnn_and_lose_the_seam_windows():
    q = _clip(T=120)
    src = diversity.features(q)
    swapped = diversity.features(np.concatenate([q[60:], q[:60]]))
    pnn = diversity.global_diversity(swapped, src)
    assert pnn.value == 0.0
    assert pnn.segments == [(0, 60, 60), (60, 120, 0)]
    # Windows of the source that cross frame 60 are not in the sample.
    cov = diversity.coverage(swapped, src, eps=1e-3)
    assert cov == pytest.approx(1 - 29 / 91)  # 91 windows of 30 frames, 29 straddle the seam
    # Local diversity: only the sample windows across its seam have no exact match.
    loc = diversity.local_diversity(swapped, src)
    assert 0 < loc < diversity.local_diversity(diversity.features(_clip(seed=9)), src)
    # Segments shorter than T_min are not allowed: three 20-frame pieces cost something.
    thirds = diversity.features(np.concatenate([q[40:60], q[0:20], q[20:40]]))
    assert diversity.global_diversity(thirds, src, t_min=30).value > 1e-3
    assert diversity.global_diversity(thirds, src, t_min=20).value < 1e-6


@pytest.mark.parametrize("mode", ["code", "paper"])
def test_pnn_matches_the_brute_force_recursion(mode):
    rng = np.random.default_rng(3)
    for lq, lt, t_min in ((13, 9, 3), (10, 16, 4), (9, 9, 2)):
        q = rng.normal(size=(lq, 4))
        t = rng.normal(size=(lt, 4))
        c = diversity.frame_costs(q, t, mode)
        got = diversity.global_diversity(q, t, t_min=t_min, mode=mode)
        assert got.value == pytest.approx(_brute_pnn(c, t_min), rel=1e-10, abs=1e-12)
        # The backtracked segmentation has exactly that cost and respects T_min.
        assert sum(c[a, got.labels[a]] for a in range(lq)) / lq == pytest.approx(got.value, rel=1e-10)
        assert all(b - a >= t_min for a, b, _ in got.segments)
        assert all(0 <= k and k + (b - a) <= lt for a, b, k in got.segments)


def test_window_costs_and_nn_against_direct_sums():
    rng = np.random.default_rng(1)
    q, t = rng.normal(size=(17, 3)), rng.normal(size=(11, 3))
    c = diversity.frame_costs(q, t)
    np.testing.assert_allclose(c, np.linalg.norm(q[:, None] - t[None], axis=-1), atol=1e-12)
    w = diversity.window_costs(diversity.diagonal_prefix(c), 4)
    assert w.shape == (14, 8)
    for i in (0, 5, 13):
        for k in (0, 3, 7):
            assert w[i, k] == pytest.approx(sum(c[i + m, k + m] for m in range(4)))
    with pytest.raises(diversity.MetricsError, match="does not fit"):
        diversity.window_costs(diversity.diagonal_prefix(c), 12)
    with pytest.raises(diversity.MetricsError, match="at least 30 frames"):
        diversity.global_diversity(q, t)


def test_features_and_contacts():
    from pipeline.motion.clip import Motion
    from pipeline.motion.skeleton import Skeleton

    q = _clip(T=10, J=3)
    f = diversity.features(q)
    assert f.shape == (10, 18)
    # The first two rows of each rotation matrix (the official evaluation's 6D).
    from pipeline.motion.rotations import quat_to_matrix

    m = quat_to_matrix(q[4, 1].astype(np.float64))
    np.testing.assert_allclose(f[4, 6:12], np.r_[m[0], m[1]], atol=1e-12)
    skel = Skeleton(("a", "b", "c"), np.array([-1, 0, 1]), np.array([[0, 0, 0], [0, 50, 0], [0, 50, 0]]))
    root = np.zeros((10, 3))
    root[5:, 0] = np.arange(5) * 10  # moves 10 cm a frame from frame 5 on
    lab = diversity.contact_labels(Motion(skel, np.tile(q[:1], (10, 1, 1)), root, 30.0), ["c"])
    assert lab[:, 0].tolist() == [0, 1, 1, 1, 1, 1, 0, 0, 0, 0]
    assert diversity.features(q, lab[:, :1].repeat(1, 0)).shape == (10, 19)


def test_dance_sized_pnn_is_fast_and_small_in_memory():
    """2× a 1,901-frame clip: the official dense float64 tensor [L_Q, L_Q+1, L_T] would be
    220 GB; here C and P (2 × 58 MB) and a second."""
    import time
    import tracemalloc

    src = diversity.features(_clip(T=1901, J=4, seed=2))
    sample = np.concatenate([src[900:1901], src[0:900], src[0:1901]])  # 3,802 frames, 3 pieces
    tracemalloc.start()
    t0 = time.perf_counter()
    pnn = diversity.global_diversity(sample, src)
    took = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert pnn.value == 0.0 and [s[2] for s in pnn.segments] == [900, 0, 0]
    np.testing.assert_array_equal(pnn.labels, np.r_[900:1901, 0:900, 0:1901])
    assert peak < 400e6, peak  # C and P: 2 × 3802 × 1902 float64 ≈ 116 MB, plus temporaries
    print(f"PNN {len(sample)} vs {len(src)} frames: {took:.2f} s, peak {peak / 1e6:.0f} MB")
