"""Posture offsets: the same motion as a differently set-up rig or a stylised character would
carry it. Used to train for robustness (``tween train --posture``) and to measure it
(``tween bench --posture``)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.motion.rotations import quat_mul, slerp_pairs


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


def tempo_factor(rng: np.random.Generator, max_change: float) -> float:
    """A playback speed, log-uniform between 1 / (1 + max_change) and 1 + max_change: the
    same motion performed faster or slower, as another actor or a stylised take would."""
    span = np.log1p(max_change)
    return float(np.exp(rng.uniform(-span, span)))


def time_warp(rot: np.ndarray, root: np.ndarray, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Windows (B, N, J, 4) / (B, N, 3) resampled to ``frames`` frames spanning the same time
    (first and last frames kept): rotations by SLERP, the root linearly. N > frames plays the
    motion faster, N < frames slower."""
    n = rot.shape[1]
    t = np.linspace(0.0, n - 1.0, frames)
    i = np.minimum(np.floor(t).astype(np.int64), n - 2)
    f = t - i
    w = np.broadcast_to(f[None, :, None], rot.shape[:1] + (frames,) + rot.shape[2:3])
    out_rot = slerp_pairs(rot[:, i], rot[:, i + 1], w).astype(rot.dtype)
    r = root.astype(np.float64)
    out_root = (r[:, i] + f[None, :, None] * (r[:, i + 1] - r[:, i])).astype(root.dtype)
    return out_rot, out_root
