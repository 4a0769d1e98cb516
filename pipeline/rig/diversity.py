"""GANimator's evaluation metrics (Li et al. 2022, §7; ``ganimator-notes.md`` §7 and §9):
coverage, global diversity (patched nearest neighbour, PNN) and local diversity, against
the one training clip.

**Features and costs.** Each frame is the rotation features of every joint (root included,
root *position* excluded): by default the official evaluation's convention, the 6D form as
the first two **rows** of each local rotation matrix, optionally followed by foot-contact
labels, with the **non-squared** L2 norm as the per-frame cost and a window's cost the sum
of its frames' costs (``mode="code"``; the coverage threshold ε = 2.0 belongs to this cost).
``mode="paper"`` is the paper's equation instead: squared Frobenius norm of the difference
of the full 3×3 local rotation matrices (no contacts).

* ``NN(Q1, Q2) = (1/L1) · min over windows Q_w of Q2 of cost(Q1, Q_w)``;
* **coverage** = the fraction of the clip's windows of ``L_c = 30`` frames whose NN in the
  sample is below ε;
* **local diversity** = the mean over the sample's windows of ``L_d = 15`` frames of their
  NN in the clip;
* **global diversity** ``L_PNN = D(L_Q) / L_Q``, with the segmentation DP of Appendix B:
  ``D(i) = min_{j ≤ i − T_min, k} D(j) + cost(j, i, k)``, segments of at least
  ``T_min = 30`` frames, each matched to a contiguous run of the clip.

**How it is computed** (no dense ``[L_Q, L_Q+1, L_T]`` tensor as in the official code):
one per-frame cost matrix ``C[a, b]`` (L_Q × L_T) and its prefix sums along the diagonals,
``P[a+1, b+1] = P[a, b] + C[a, b]``; every window cost is then ``P[i+L, k+L] − P[i, k]``,
O(L_Q·L_T) memory. In the DP a segment ``Q[j:i]`` against ``T[j+d : i+d]`` costs
``P[i, i+d] − P[j, j+d]``, so ``D(i) = min_d (P[i, i+d] + min_{j ≤ i−T_min} (D(j) − P[j, j+d]))``:
the inner minimum is a running minimum per diagonal ``d``, updated once per ``i``. That
makes PNN O(L_Q·(L_Q + L_T)) time (one vectorised numpy pass per sample frame) instead of
the paper's O(L_Q²·L_T), with the same optimum.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.errors import TweenError
from pipeline.motion.rotations import quat_to_matrix

L_COVERAGE = 30  # L_c: training windows for coverage (1 s at 30 fps)
T_MIN = 30  # shortest PNN segment
L_LOCAL = 15  # L_d: sample windows for local diversity
COVERAGE_EPS = 2.0  # the official evaluation's threshold, for mode="code"
CONTACT_EPS_M = 0.018  # foot velocity (metres per frame) below which a contact joint touches


class MetricsError(TweenError):
    """The sequences are too short or do not fit each other."""


def features(rotations: np.ndarray, contacts: np.ndarray | None = None, mode: str = "code") -> np.ndarray:
    """Per-frame feature vectors (T, F) from local rotations (T, J, 4) xyzw."""
    q = np.asarray(rotations, np.float64)
    m = quat_to_matrix(q.reshape(-1, 4)).reshape(q.shape[:-1] + (3, 3))
    if mode == "paper":
        return m.reshape(len(q), -1)
    if mode != "code":
        raise ValueError(f"mode must be 'code' or 'paper', not {mode!r}")
    f = np.concatenate([m[..., 0, :], m[..., 1, :]], axis=-1).reshape(len(q), -1)  # first two rows
    if contacts is not None:
        f = np.concatenate([f, np.asarray(contacts, np.float64).reshape(len(q), -1)], axis=1)
    return f


def contact_labels(motion, joints, eps_m: float = CONTACT_EPS_M) -> np.ndarray:
    """GANimator's label rule: 1 where a contact joint moves less than ``eps_m`` metres per
    frame (positions by FK, in the skeleton's unit times metersPerUnit); frame 0 is 0."""
    idx = [motion.skeleton.index(j) for j in joints]
    pos = motion.positions()[:, idx].astype(np.float64) * motion.skeleton.meters_per_unit
    vel = np.zeros(pos.shape[:2])
    vel[1:] = np.linalg.norm(pos[1:] - pos[:-1], axis=-1)
    lab = (vel < eps_m).astype(np.float64)
    lab[0] = 0.0
    return lab


def frame_costs(q: np.ndarray, t: np.ndarray, mode: str = "code") -> np.ndarray:
    """C[a, b] = cost between frame a of ``q`` and frame b of ``t`` (features, (L, F))."""
    q = np.asarray(q, np.float64)
    t = np.asarray(t, np.float64)
    if q.ndim != 2 or t.ndim != 2 or q.shape[1] != t.shape[1]:
        raise MetricsError(f"feature shapes {q.shape} and {t.shape} do not match")
    nq, nt = (q * q).sum(1), (t * t).sum(1)
    sq = nq[:, None] + nt[None, :] - 2.0 * (q @ t.T)
    # The expansion loses the small distances to rounding (identical frames would cost
    # ~1e-8 after the square root): recompute those pairs from their differences.
    near = np.nonzero(sq < 1e-6 * (nq[:, None] + nt[None, :] + 1e-12))
    for s in range(0, len(near[0]), 1 << 16):
        a, b = near[0][s : s + (1 << 16)], near[1][s : s + (1 << 16)]
        sq[a, b] = ((q[a] - t[b]) ** 2).sum(1)
    sq = np.maximum(sq, 0.0)
    return sq if mode == "paper" else np.sqrt(sq)


def diagonal_prefix(c: np.ndarray) -> np.ndarray:
    """P (L_Q+1, L_T+1) with P[a+1, b+1] = P[a, b] + C[a, b] (prefix sums along diagonals)."""
    n, m = c.shape
    p = np.zeros((n + 1, m + 1))
    for a in range(n):  # one vectorised row at a time: O(n·m) work and memory
        np.add(p[a, :m], c[a], out=p[a + 1, 1:])
    return p


def window_costs(p: np.ndarray, length: int) -> np.ndarray:
    """W[i, k] = Σ_{m<length} C[i+m, k+m] for every pair of windows (from the prefix ``p``)."""
    n, m = p.shape[0] - 1, p.shape[1] - 1
    if length > n or length > m:
        raise MetricsError(f"a {length}-frame window does not fit sequences of {n} and {m} frames")
    return p[length:, length:] - p[: n - length + 1, : m - length + 1]


def coverage(sample: np.ndarray, source: np.ndarray, length: int = L_COVERAGE, eps: float = COVERAGE_EPS,
             mode: str = "code") -> float:  # fmt: skip
    """Fraction of the source's ``length``-frame windows with NN(window, sample) < ``eps``."""
    w = window_costs(diagonal_prefix(frame_costs(source, sample, mode)), length)
    return float(np.mean(w.min(axis=1) / length < eps))


def local_diversity(
    sample: np.ndarray, source: np.ndarray, length: int = L_LOCAL, mode: str = "code"
) -> float:
    """Mean over the sample's ``length``-frame windows of NN(window, source)."""
    w = window_costs(diagonal_prefix(frame_costs(sample, source, mode)), length)
    return float(np.mean(w.min(axis=1) / length))


@dataclass
class PNN:
    value: float  # D(L_Q) / L_Q
    labels: np.ndarray  # (L_Q,) the source frame each sample frame is matched to
    segments: list[tuple[int, int, int]]  # (start, stop, source start) per segment


def global_diversity(sample: np.ndarray, source: np.ndarray, t_min: int = T_MIN, mode: str = "code") -> PNN:
    """Patched nearest neighbour: the cheapest cover of the sample by source runs of at
    least ``t_min`` frames (exact optimum of Appendix B's DP)."""
    c = frame_costs(sample, source, mode)
    lq, lt = c.shape
    if lq < t_min or lt < t_min:
        raise MetricsError(f"PNN needs at least {t_min} frames in the sample ({lq}) and the source ({lt})")
    p = diagonal_prefix(c)
    # Diagonal d = (source frame − sample frame) is stored at offset d + lq.
    best = np.full(lq + lt + 1, np.inf)
    best_j = np.zeros(lq + lt + 1, np.int64)
    d = np.full(lq + 1, np.inf)
    d[0] = 0.0
    back_j = np.zeros(lq + 1, np.int64)
    back_d = np.zeros(lq + 1, np.int64)
    for i in range(t_min, lq + 1):
        j = i - t_min  # the segment start that becomes admissible at this i
        if np.isfinite(d[j]):
            sl = slice(lq - j, lq - j + lt + 1)
            cand = d[j] - p[j]
            better = cand < best[sl]
            best[sl] = np.where(better, cand, best[sl])
            best_j[sl] = np.where(better, j, best_j[sl])
        sl = slice(lq - i, lq - i + lt + 1)
        tot = best[sl] + p[i]
        o = int(np.argmin(tot))
        d[i] = tot[o]
        back_j[i], back_d[i] = best_j[lq - i + o], o - i
    labels = np.empty(lq, np.int64)
    segments = []
    i = lq
    while i > 0:
        j, off = int(back_j[i]), int(back_d[i])
        labels[j:i] = np.arange(j, i) + off
        segments.append((j, i, j + off))
        i = j
    return PNN(float(d[lq] / lq), labels, segments[::-1])


def evaluate(samples: list[np.ndarray], source: np.ndarray, mode: str = "code") -> dict:
    """Mean coverage, global and local diversity over samples (feature arrays)."""
    cov = [coverage(s, source, mode=mode) for s in samples]
    glob = [global_diversity(s, source, mode=mode).value for s in samples]
    loc = [local_diversity(s, source, mode=mode) for s in samples]
    return {
        "samples": len(samples),
        "coverage": float(np.mean(cov)),
        "global_diversity": float(np.mean(glob)),
        "local_diversity": float(np.mean(loc)),
        "per_sample": [
            {"coverage": a, "global_diversity": b, "local_diversity": c}
            for a, b, c in zip(cov, glob, loc, strict=True)
        ],
    }
