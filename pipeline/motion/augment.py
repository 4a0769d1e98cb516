"""Posture offsets: the same motion as a differently set-up rig, a stylised character or another
actor would carry it. Measured with them (``tween bench --posture``) and trained with them for
robustness (``tween train --joint-offsets``)."""

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


def joint_offsets(rot: np.ndarray, rng: np.random.Generator, sigma_deg: float, prob: float) -> np.ndarray:
    """Right-multiply each joint but the root joint (0) of a share ``prob`` of windows
    (B, N, J, 4) by its own constant rotation: random axis, angle half-normal with RMS
    ``sigma_deg``. Another actor, or a retarget onto the model skeleton, carries such small
    systematic offsets from the training actors' poses; the root is left alone so the
    window's facing and path stay the capture's."""
    B, _, J = rot.shape[:3]
    axis = rng.normal(size=(B, J - 1, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    angle = np.abs(rng.normal(scale=np.radians(sigma_deg), size=(B, J - 1, 1)))
    on = np.flatnonzero(rng.random(B) < prob)
    off = Rotation.from_rotvec((axis[on] * angle[on]).reshape(-1, 3)).as_quat().reshape(len(on), 1, J - 1, 4)
    out = rot.copy()  # untouched windows and the root joint stay bit for bit
    part = rot[on, :, 1:].astype(np.float64)
    out[on, :, 1:] = quat_mul(part, np.broadcast_to(off, part.shape)).astype(rot.dtype)
    return out
