"""Training batches: random windows of train clips with a random key layout per batch.

Key layouts (curriculum: the longest gap grows from ``gap_start`` to ``gap_end`` frames
over the first ``curriculum`` fraction of training):
- "context": 10 context keys, one target after a gap (the benchmark's task), then sparse
  keys to the end of the window;
- "sparse": keys every 1..max_gap frames (an animator's blocking).
Gaps are drawn log-uniformly in [1, max_gap]. Some keys can be made partial
(:func:`sample_joint_keys`): the root only, the rotations only, or some joints only; or
partial keys can be added inside the gaps of the full keys (:func:`insert_partial_keys`), as
an animator adds a root or a leg key to blocked poses.
"""

from __future__ import annotations

import numpy as np

from pipeline.data.cache import ClipSet

PARTIAL_LAYOUTS = ("convert", "insert")  # sample_joint_keys, insert_partial_keys


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
        if rng.random() < share:
            m[k] = partial_pattern(rng, n_joints)
    return m


def partial_pattern(rng: np.random.Generator, n_joints: int) -> np.ndarray:
    """(J + 1,) what one partial key keys: the root only, the rotations only, or a random half
    of joints and root (at least one)."""
    m = np.ones(n_joints + 1, bool)
    kind = rng.integers(3)
    if kind == 0:
        m[:n_joints] = False
    elif kind == 1:
        m[n_joints] = False
    else:
        m = rng.random(n_joints + 1) < 0.5
        m[rng.integers(n_joints + 1)] = True
    return m


def insert_partial_keys(
    rng: np.random.Generator, keys: np.ndarray, n_joints: int, min_gap: int = 8
) -> tuple[np.ndarray, np.ndarray]:
    """(keys, (K', J + 1) mask): ``keys`` (all full) plus one partial key at a random frame
    inside each gap of at least ``min_gap`` frames, at least 2 frames from either end. With no
    such gap, the keys stay as they are (all full)."""
    new, rows = [], []
    for a, b in zip(keys[:-1], keys[1:], strict=True):
        if b - a >= min_gap:
            new.append(int(rng.integers(a + 2, b - 1)))
            rows.append(partial_pattern(rng, n_joints))
    mask = np.ones((len(keys) + len(new), n_joints + 1), bool)
    if not new:
        return keys, mask
    merged = np.concatenate([keys, new])
    order = np.argsort(merged, kind="stable")
    mask[len(keys) :] = np.array(rows)
    return merged[order], mask[order]


def sample_batch(
    clips: ClipSet, rng: np.random.Generator, batch: int, length: int, where: list | None = None
):
    """(rot (B, L, J, 4), root (B, L, 3)) windows from clips at least ``length`` long; each
    window's (clip, first frame in the clip) is appended to ``where`` when given."""
    ok = np.flatnonzero(clips.lengths >= length)
    # p=None draws exactly as before: the train split's and --data's batches stay bit for bit.
    pick = rng.choice(ok, size=batch, p=clips.draw_p(ok))
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
