"""Rotation conversions on numpy arrays of any leading shape.

Quaternions are scalar-last (x, y, z, w) everywhere in this project: it is scipy's order
and the memory order of USD's ``Vt.QuatfArray``. Conversions go through
``scipy.spatial.transform.Rotation``; the few helpers written here (6D, SLERP on arrays,
continuity) are ones scipy has no batched form for.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def _flat(a: np.ndarray, tail: int) -> tuple[np.ndarray, tuple[int, ...]]:
    a = np.asarray(a)
    lead = a.shape[: a.ndim - tail]
    return a.reshape((-1,) + a.shape[a.ndim - tail :]), lead


def quat_identity(shape: tuple[int, ...] = ()) -> np.ndarray:
    q = np.zeros(shape + (4,), np.float32)
    q[..., 3] = 1.0
    return q


def quat_normalize(q: np.ndarray) -> np.ndarray:
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b (apply b first, then a), broadcasting."""
    a, b = np.broadcast_arrays(a, b)
    fa, lead = _flat(np.require(a, np.float64, ["C", "W"]), 1)
    fb, _ = _flat(np.require(b, np.float64, ["C", "W"]), 1)
    out = (Rotation.from_quat(fa) * Rotation.from_quat(fb)).as_quat()
    return out.reshape(lead + (4,)).astype(a.dtype, copy=False)


def quat_inv(q: np.ndarray) -> np.ndarray:
    out = np.array(q, copy=True)
    out[..., :3] *= -1
    return out


def quat_apply(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v (..., 3) by quaternions q (..., 4), broadcasting."""
    lead = np.broadcast_shapes(np.shape(q)[:-1], np.shape(v)[:-1])
    fq = np.require(np.broadcast_to(q, lead + (4,)), np.float64, ["C", "W"]).reshape(-1, 4)
    fv = np.require(np.broadcast_to(v, lead + (3,)), np.float64, ["C", "W"]).reshape(-1, 3)
    out = Rotation.from_quat(fq).apply(fv).reshape(lead + (3,))
    return out.astype(np.result_type(q, v), copy=False)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    fq, lead = _flat(q, 1)
    return Rotation.from_quat(fq).as_matrix().reshape(lead + (3, 3)).astype(q.dtype, copy=False)


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    fm, lead = _flat(m, 2)
    return Rotation.from_matrix(fm).as_quat().reshape(lead + (4,)).astype(m.dtype, copy=False)


def euler_to_quat(angles_deg: np.ndarray, order: str) -> np.ndarray:
    """Intrinsic Euler angles in channel order (e.g. "ZXY" means R = Rz·Rx·Ry), degrees."""
    fa, lead = _flat(angles_deg, 1)
    q = Rotation.from_euler(order.upper(), fa, degrees=True).as_quat()
    return q.reshape(lead + (4,))


def quat_to_euler(q: np.ndarray, order: str) -> np.ndarray:
    fq, lead = _flat(q, 1)
    e = Rotation.from_quat(fq).as_euler(order.upper(), degrees=True)
    return e.reshape(lead + (3,))


def matrix_to_6d(m: np.ndarray) -> np.ndarray:
    """The continuous 6D representation (Zhou et al. 2019): the first two columns."""
    return np.concatenate([m[..., :, 0], m[..., :, 1]], axis=-1)


def sixd_to_matrix(d6: np.ndarray) -> np.ndarray:
    """Gram–Schmidt back to a rotation matrix; scipy has no 6D form."""
    a1, a2 = d6[..., :3], d6[..., 3:]
    b1 = a1 / np.linalg.norm(a1, axis=-1, keepdims=True)
    b2 = a2 - (b1 * a2).sum(-1, keepdims=True) * b1
    b2 = b2 / np.linalg.norm(b2, axis=-1, keepdims=True)
    b3 = np.cross(b1, b2)
    return np.stack([b1, b2, b3], axis=-1)


def quat_to_6d(q: np.ndarray) -> np.ndarray:
    return matrix_to_6d(quat_to_matrix(q))


def sixd_to_quat(d6: np.ndarray) -> np.ndarray:
    return matrix_to_quat(sixd_to_matrix(d6))


def quat_continuity(q: np.ndarray, axis: int = 0) -> np.ndarray:
    """Flip q to -q wherever that is closer to the previous sample along ``axis``."""
    q = np.moveaxis(np.array(q, copy=True), axis, 0)
    for t in range(1, q.shape[0]):
        flip = (q[t] * q[t - 1]).sum(-1) < 0
        q[t][flip] *= -1
    return np.moveaxis(q, 0, axis)


def slerp(q0: np.ndarray, q1: np.ndarray, w: np.ndarray, lerp_eps: float = 0.01) -> np.ndarray:
    """Shortest-arc SLERP between q0 and q1 (..., 4) at weights w (T,), giving (T, ..., 4).

    Falls back to normalised LERP where 1 - |dot| < ``lerp_eps`` (PROTOCOL.md). Written
    here because scipy's Slerp interpolates one key track, not arrays of joint pairs.
    """
    q0 = np.asarray(q0, np.float64)
    w = np.asarray(w, np.float64).reshape((-1,) + (1,) * (q0.ndim - 1))
    return slerp_pairs(q0[None], np.asarray(q1, np.float64)[None], w, lerp_eps)


def slerp_pairs(q0: np.ndarray, q1: np.ndarray, w: np.ndarray, lerp_eps: float = 0.01) -> np.ndarray:
    """Elementwise SLERP: one weight per pair, ``w`` broadcastable to ``q0.shape[:-1]``."""
    q0 = np.asarray(q0, np.float64)
    q1 = np.asarray(q1, np.float64)
    w = np.asarray(w, np.float64)[..., None]
    dot = (q0 * q1).sum(-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    near = (1.0 - dot) < lerp_eps
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_t = np.where(near, 1.0, np.sin(theta))
    s0 = np.where(near, 1.0 - w, np.sin((1.0 - w) * theta) / sin_t)
    s1 = np.where(near, w, np.sin(w * theta) / sin_t)
    out = s0 * q0 + s1 * q1
    return quat_normalize(out)
