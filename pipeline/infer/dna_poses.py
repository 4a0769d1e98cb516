"""Motion DNA (Generative Tweening §4.2): representative poses that a fill should contain.

A DNA is a handful of poses, usually picked from a reference clip, that steer a take: the
generator embeds them (``pipeline/networks/dna.py``) and was trained to put such poses into
the in-betweens. Each pose goes in as root-relative joint positions turned to face +X, so
where the reference clip stands and faces does not matter.
"""

from __future__ import annotations

import numpy as np

from pipeline.motion.fk import fk
from pipeline.motion.rotations import quat_apply

POSE_SCALE = 100.0  # centimetres in, metres to the network
MAX_POSES = 8


def n_dna_channels(n_joints: int) -> int:
    """Root-relative positions of every joint but the root."""
    return 3 * (n_joints - 1)


def dna_poses(rot: np.ndarray, root: np.ndarray, skeleton) -> np.ndarray:
    """(R, J, 4) local rotations and (R, 3) roots -> (3 (J − 1), R) network input."""
    from pipeline.data.protocol import facing_turn

    _, pos = fk(np.asarray(rot, np.float64), np.asarray(root, np.float64), skeleton.parents, skeleton.offsets)
    q = facing_turn(pos, skeleton)
    rel = quat_apply(q[:, None], pos[:, 1:] - pos[:, :1])
    return (rel.reshape(len(rel), -1).T / POSE_SCALE).astype(np.float32)


def representative_frames(rot: np.ndarray, count: int, spacing: int = 10, frames=None) -> np.ndarray:
    """The ``count`` frames of (N, J, 4) ``rot`` whose joints turn most between their neighbours
    (the paper's rule), at least ``spacing`` frames apart, in time order; ``frames`` limits the
    choice to those frames."""
    n = len(rot)
    cand = np.arange(n) if frames is None else np.asarray(frames)
    if n < 3 or len(cand) == 0:
        return np.sort(cand[:count]) if len(cand) else np.zeros(0, np.int64)
    a, b = rot[np.clip(cand - 1, 0, n - 1)], rot[np.clip(cand + 1, 0, n - 1)]
    dot = np.abs((a * b).sum(-1)).clip(0, 1)
    change = (2 * np.arccos(dot)).sum(-1)
    picked: list[int] = []
    for i in np.argsort(-change, kind="stable"):
        if all(abs(int(cand[i]) - p) >= spacing for p in picked):
            picked.append(int(cand[i]))
            if len(picked) == count:
                break
    return np.array(sorted(picked), np.int64)
