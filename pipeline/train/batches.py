"""Training batches: random windows of train clips with a random key layout per batch.

Key layouts (curriculum: the longest gap grows from ``gap_start`` to ``gap_end`` frames
over the first ``curriculum`` fraction of training):
- "context": 10 context keys, one target after a gap (the benchmark's task), then sparse
  keys to the end of the window;
- "sparse": keys every 1..max_gap frames (an animator's blocking).
Gaps are drawn log-uniformly in [1, max_gap]. Some keys can be made partial
(:func:`sample_joint_keys`): the root only, the rotations only, or some joints only.
"""

from __future__ import annotations

import numpy as np

from pipeline.data.cache import ClipSet


def sample_keys(rng: np.random.Generator, n: int, max_gap: int) -> np.ndarray:
    keys = [0]
    if rng.random() < 0.5:
        keys = list(range(10))
    while keys[-1] < n - 1:
        # Log-uniform gaps: short transitions are as common as long ones, so the network
        # learns to leave a near-perfect interpolation alone.
        gap = int(np.round(np.exp(rng.uniform(0.0, np.log(max_gap + 0.5)))))
        keys.append(min(keys[-1] + max(gap, 1), n - 1))
    return np.array(keys, np.int64)


def sample_joint_keys(rng: np.random.Generator, n_keys: int, n_joints: int, share: float = 0.5) -> np.ndarray:
    """(K, J + 1) mask: each key but the first and last is partial with probability ``share``,
    keying the root only, the rotations only (no root), or a random half of joints and root."""
    m = np.ones((n_keys, n_joints + 1), bool)
    for k in range(1, n_keys - 1):
        if rng.random() >= share:
            continue
        kind = rng.integers(3)
        if kind == 0:
            m[k, :n_joints] = False
        elif kind == 1:
            m[k, n_joints] = False
        else:
            m[k] = rng.random(n_joints + 1) < 0.5
            m[k, rng.integers(n_joints + 1)] = True
    return m


def sample_batch(
    clips: ClipSet, rng: np.random.Generator, batch: int, length: int, where: list | None = None
):
    """(rot (B, L, J, 4), root (B, L, 3)) windows from clips at least ``length`` long; each
    window's (clip, first frame in the clip) is appended to ``where`` when given."""
    ok = np.flatnonzero(clips.lengths >= length)
    pick = rng.choice(ok, size=batch)
    rots, roots = [], []
    for c in pick:
        off = int(rng.integers(0, clips.lengths[c] - length + 1))
        s = clips.starts[c] + off
        rots.append(clips.rotations[s : s + length])
        roots.append(clips.roots[s : s + length])
        if where is not None:
            where.append((int(c), off))
    return np.stack(rots), np.stack(roots)


def foot_contacts(pos: np.ndarray, feet: list[int], threshold: float = 1.0) -> np.ndarray:
    """(B, N, 4) labels: squared displacement from the previous frame below ``threshold`` cm²."""
    p = pos[:, :, feet]
    d = np.square(np.diff(p, axis=1, prepend=p[:, :1])).sum(-1)
    return (d < threshold).astype(np.float32)
