"""Posture offsets: the same motion as a differently set-up rig or a stylised character would
carry it. Used to train for robustness (``tween train --posture``) and to measure it
(``tween bench --posture``)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.motion.rotations import quat_mul


def posture_offsets(rot: np.ndarray, rng: np.random.Generator, max_deg: float, prob: float) -> np.ndarray:
    """Right-multiply each joint of a share ``prob`` of windows by its own constant rotation
    (random axis, angle uniform up to ``max_deg``): the same motion on a differently set-up rig
    or a stylised posture. A studio rig retargeted onto the model skeleton arrives with such
    offsets, and a model that only knows the actors' postures fails on them (model card)."""
    B, _, J = rot.shape[:3]
    axis = rng.normal(size=(B, J, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    angle = np.radians(max_deg) * rng.random((B, J, 1)) * (rng.random((B, 1, 1)) < prob)
    off = Rotation.from_rotvec((axis * angle).reshape(-1, 3)).as_quat().reshape(B, 1, J, 4)
    return quat_mul(rot.astype(np.float64), np.broadcast_to(off, rot.shape)).astype(rot.dtype)
