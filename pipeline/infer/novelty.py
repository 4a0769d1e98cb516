"""How familiar a shot's keys are to a network: their distance to the poses it was trained on.

The trusted fill (:mod:`pipeline.infer.trust`) leans toward the network on gaps longer than
its probes' holes because, on the motion it was trained on, the network's lead over the spline
grows with the gap. On poses it never saw that prior does not hold (on the CMU takes its lead
shrinks as gaps grow; docs/trust.md). The keys say which case a shot is: each key pose's
nearest pose in the model's pose bank (:mod:`pipeline.data.posebank`), as the mean per-joint
distance in cm of root-relative, facing-aligned joint positions; the shot's **novelty** is the
median over its keys (at most MAX_KEYS of them, evenly spread). Familiarity is 1 up to :data:`FAMILIAR_CM`, 0 from :data:`NOVEL_CM`,
linear between.
"""

from __future__ import annotations

import numpy as np

from pipeline.data.posebank import pose_features

#: Novelty (cm) up to which a shot counts as the training data's own. Eval-split shots of the
#: blocking bench (keys every 30): at most 2.7 cm (median 1.3) from the shipped bank
#: (experiments/key_novelty.py).
FAMILIAR_CM = 3.0
#: Novelty (cm) from which a shot counts as unseen. CMU shots: at least 4.4 cm (median 8.1);
#: eval shots with posture offsets up to 30 degrees: at least 4.3 (median 10.0).
NOVEL_CM = 5.0
#: At most this many keys of a shot are compared (evenly spread): time stays bounded on
#: shots keyed on every frame, and the median over 256 keys is as good as over all.
MAX_KEYS = 256
#: How far (relative) a bank pose's quick distance may lie above the least quick distance
#: and still be measured exactly. Both measures sum the same non-negative float32 terms
#: (21 joints, 3 coordinates) in other orders, so they differ by at most about 30 float32
#: roundings (2e-6 relative): the exact nearest is always among those measured. SLACK (in the
#: features' units) covers squares below float32's normal range, whose roundings are absolute.
MARGIN = 1e-4
SLACK = 1e-15


def _exact(x: np.ndarray, bank: np.ndarray) -> np.ndarray:
    """(M, P) mean per-joint distances of the poses ``x`` (M, J, 3) to ``bank`` (P, J, 3):
    the measure novelty reports, float32 as numpy computes it."""
    return np.linalg.norm(x[:, None] - bank[None], axis=-1).mean(-1)


def _quick(x: np.ndarray, by_axis: np.ndarray) -> np.ndarray:
    """(P,) the mean per-joint distances of one pose ``x`` (J, 3) to the bank laid out as
    ``by_axis`` (J, 3, P): the bank's poses run along the last axis, so every step is one
    pass over contiguous memory (the exact measure's sums over 3 and 21 values are numpy's
    slowest loops), in another order than the exact measure's."""
    d = by_axis - x[:, :, None]
    d *= d
    sq = d[:, 0] + d[:, 1]
    sq += d[:, 2]
    np.sqrt(sq, out=sq)
    return sq.sum(0) / np.float32(len(x))


def nearest_cm(features: np.ndarray, bank: np.ndarray, cm_per_unit: float = 1.0) -> np.ndarray:
    """(M,) each pose's mean per-joint distance to its nearest bank pose, in cm. ``features``
    (M, J, 3) from :func:`pipeline.data.posebank.pose_features`, ``bank`` (P, J, 3).

    Bit for bit the least of :func:`_exact` over the whole bank: a quick pass
    (:func:`_quick`) finds the poses within MARGIN of the nearest, and only those are
    measured exactly (200 keys against 4,096 poses: 0.41 s when all were, 0.04 s so)."""
    x = np.asarray(features, np.float32)
    bank = np.asarray(bank, np.float32)
    if x.shape[1:] != bank.shape[1:]:
        raise ValueError(f"poses of {x.shape[1]} joints against a bank of {bank.shape[1]}")
    by_axis = np.ascontiguousarray(bank.transpose(1, 2, 0))
    out = np.empty(len(x))
    for i, pose in enumerate(x):
        with np.errstate(all="ignore"):  # a pose beyond float32 squares is measured exactly below
            quick = _quick(pose, by_axis)
        least = quick.min()
        near = np.flatnonzero(quick <= least * (1 + MARGIN) + SLACK)
        if not (np.isfinite(least) and least < 1e30):  # NaN or overflow: all of the bank, as ever
            near = slice(None)
        out[i] = _exact(x[i : i + 1], bank[near]).min()
    return out * cm_per_unit


def novelty_cm(rots: np.ndarray, roots: np.ndarray, bank: np.ndarray, skeleton) -> np.ndarray:
    """(N,) the median over the keys of each shot's key poses' distance to the bank (cm).
    ``rots`` (N, K, J, 4) and ``roots`` (N, K, 3): the key frames of N shots."""
    rots, roots = np.asarray(rots), np.asarray(roots)
    if rots.shape[1] > MAX_KEYS:
        pick = np.unique(np.round(np.linspace(0, rots.shape[1] - 1, MAX_KEYS)).astype(int))
        rots, roots = rots[:, pick], roots[:, pick]
    N, K, J = rots.shape[:3]
    feats = pose_features(rots.reshape(N * K, J, 4), roots.reshape(N * K, 3), skeleton)
    cm = 100.0 * float(getattr(skeleton, "meters_per_unit", 0.01))
    return np.median(nearest_cm(feats, bank, cm).reshape(N, K), axis=1)


def familiarity(novelty: float | None) -> float:
    """1 for a shot as familiar as the training data, 0 for an unseen one. None (a model
    without a pose bank): 1, so such a model keeps the decision it had before banks (a model
    whose model.json withholds the familiar credit gets 0 from the trust decision instead)."""
    if novelty is None:
        return 1.0
    return float(np.clip((NOVEL_CM - novelty) / (NOVEL_CM - FAMILIAR_CM), 0.0, 1.0))
