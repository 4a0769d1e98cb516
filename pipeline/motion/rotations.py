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


# --- Batched quaternion arithmetic in plain numpy -------------------------------------------
# The helpers above build a scipy ``Rotation`` per call, which normalises its input, checks
# it and allocates several intermediates; on the small per-joint arrays of FK, IK and key
# matching that overhead, not the arithmetic, is most of the time. These do the same math
# as component-wise float64 array arithmetic (equal to scipy's to rounding, ~1e-16) and do
# not normalise their inputs: callers pass unit quaternions (see :func:`batch_quat_normalize`).


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot products over the last axis, summed left to right as numpy's ``(a * b).sum(-1)``
    sums a short axis (so bitwise the same), without its slow reduction over 3 or 4 items."""
    out = a[..., 0] * b[..., 0]
    for i in range(1, a.shape[-1]):
        out += a[..., i] * b[..., i]
    return out


def batch_quat_normalize(q: np.ndarray) -> np.ndarray:
    """q / |q| in float64, as scipy's ``Rotation.from_quat`` normalises."""
    q = np.asarray(q, np.float64)
    return q / np.sqrt(_dot(q, q))[..., None]


def batch_quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of unit quaternions (..., 4), broadcasting: ``quat_mul``
    without the normalisation of its inputs."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = aw * bx + bw * ax + (ay * bz - az * by)
    out[..., 1] = aw * by + bw * ay + (az * bx - ax * bz)
    out[..., 2] = aw * bz + bw * az + (ax * by - ay * bx)
    out[..., 3] = aw * bw - (ax * bx + ay * by + az * bz)
    return out


def batch_quat_conj(q: np.ndarray) -> np.ndarray:
    """The inverse of unit quaternions (float64)."""
    out = np.array(q, np.float64, copy=True)
    out[..., :3] *= -1
    return out


def batch_quat_apply(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v (..., 3) by unit quaternions q (..., 4), broadcasting:
    v + 2w (u × v) + 2 u × (u × v) with u the vector part."""
    q = np.asarray(q, np.float64)
    v = np.asarray(v, np.float64)
    ux, uy, uz, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    vx, vy, vz = v[..., 0], v[..., 1], v[..., 2]
    tx = 2 * (uy * vz - uz * vy)
    ty = 2 * (uz * vx - ux * vz)
    tz = 2 * (ux * vy - uy * vx)
    out = np.empty(np.broadcast_shapes(q.shape[:-1], v.shape[:-1]) + (3,))
    out[..., 0] = vx + w * tx + (uy * tz - uz * ty)
    out[..., 1] = vy + w * ty + (uz * tx - ux * tz)
    out[..., 2] = vz + w * tz + (ux * ty - uy * tx)
    return out


def batch_quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vectors of unit quaternions (..., 4) -> (..., 3), as scipy's ``as_rotvec``
    (the w >= 0 cover, a Taylor series below 1e-3 rad)."""
    q = np.asarray(q, np.float64)
    q = np.where(q[..., 3:] < 0, -q, q)
    u = q[..., :3]
    angle = 2 * np.arctan2(np.sqrt(_dot(u, u)), q[..., 3])
    small = angle <= 1e-3
    a2 = angle * angle
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(small, 2 + a2 / 12 + 7 * a2 * a2 / 2880, angle / np.sin(angle / 2))
    return scale[..., None] * u


def batch_rotvec_to_quat(rv: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) of rotation vectors (..., 3), as scipy's ``from_rotvec``."""
    rv = np.asarray(rv, np.float64)
    angle = np.sqrt(_dot(rv, rv))
    small = angle <= 1e-3
    a2 = angle * angle
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(small, 0.5 - a2 / 48 + a2 * a2 / 3840, np.sin(angle / 2) / angle)
    out = np.empty(rv.shape[:-1] + (4,))
    out[..., :3] = rv * scale[..., None]
    out[..., 3] = np.cos(angle / 2)
    return out


def batch_quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of quaternions (..., 4), normalised first as scipy's
    ``Rotation.from_quat(q).as_matrix()``."""
    q = batch_quat_normalize(q)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    m = np.empty(q.shape[:-1] + (3, 3))
    m[..., 0, 0] = x2 - y2 - z2 + w2
    m[..., 0, 1] = 2 * (xy - zw)
    m[..., 0, 2] = 2 * (xz + yw)
    m[..., 1, 0] = 2 * (xy + zw)
    m[..., 1, 1] = -x2 + y2 - z2 + w2
    m[..., 1, 2] = 2 * (yz - xw)
    m[..., 2, 0] = 2 * (xz - yw)
    m[..., 2, 1] = 2 * (yz + xw)
    m[..., 2, 2] = -x2 - y2 + z2 + w2
    return m


def batch_quat_to_6d(q: np.ndarray) -> np.ndarray:
    """``quat_to_6d`` (the first two matrix columns) without the scipy round trip: the six
    entries of :func:`batch_quat_to_matrix` it keeps, by the same formulas."""
    q = batch_quat_normalize(q)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    out = np.empty(q.shape[:-1] + (6,))
    out[..., 0] = x2 - y2 - z2 + w2  # m00
    out[..., 1] = 2 * (x * y + z * w)  # m10
    out[..., 2] = 2 * (x * z - y * w)  # m20
    out[..., 3] = 2 * (x * y - z * w)  # m01
    out[..., 4] = -x2 + y2 - z2 + w2  # m11
    out[..., 5] = 2 * (y * z + x * w)  # m21
    return out


def batch_sixd_to_matrix(d6: np.ndarray) -> np.ndarray:
    """:func:`sixd_to_matrix`, bitwise the same, with its norms, dot and cross product
    written out per component."""
    d6 = np.asarray(d6)
    a1, a2 = d6[..., :3], d6[..., 3:]
    b1 = a1 / np.sqrt(_dot(a1, a1))[..., None]
    b2 = a2 - _dot(b1, a2)[..., None] * b1
    b2 = b2 / np.sqrt(_dot(b2, b2))[..., None]
    m = np.empty(d6.shape[:-1] + (3, 3), np.result_type(d6, np.float32))
    m[..., :, 0] = b1
    m[..., :, 1] = b2
    m[..., 0, 2] = b1[..., 1] * b2[..., 2] - b1[..., 2] * b2[..., 1]
    m[..., 1, 2] = b1[..., 2] * b2[..., 0] - b1[..., 0] * b2[..., 2]
    m[..., 2, 2] = b1[..., 0] * b2[..., 1] - b1[..., 1] * b2[..., 0]
    return m


def batch_matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) of rotation matrices (..., 3, 3) that are orthonormal (to
    1e-12, as Gram–Schmidt's are), by the case analysis scipy's ``from_matrix`` uses (the
    largest of the diagonal and the trace picks the formula, so the same sign comes out).
    Not for matrices that scipy would first orthogonalise by SVD or reject (det <= 0)."""
    m = np.asarray(m, np.float64)
    lead = m.shape[:-2]
    m = m.reshape(-1, 9)
    tr = m[:, 0] + m[:, 4] + m[:, 8]
    choice = np.argmax(np.stack([m[:, 0], m[:, 4], m[:, 8], tr], -1), axis=-1)
    q = np.empty((len(m), 4))
    for c in np.unique(choice):  # each case on its own rows (mostly the trace's)
        rows = np.flatnonzero(choice == c)
        mc, t = m[rows].T, tr[rows]
        m00, m01, m02, m10, m11, m12, m20, m21, m22 = mc
        q[rows] = np.stack(
            (
                (1 - t + 2 * m00, m10 + m01, m20 + m02, m21 - m12),
                (m10 + m01, 1 - t + 2 * m11, m21 + m12, m02 - m20),
                (m20 + m02, m21 + m12, 1 - t + 2 * m22, m10 - m01),
                (m21 - m12, m02 - m20, m10 - m01, 1 + t),
            )[c],
            -1,
        )
    return batch_quat_normalize(q).reshape(lead + (4,))


def batch_quat_continuity(q: np.ndarray, axis: int = 0) -> np.ndarray:
    """:func:`quat_continuity` without its loop over samples, bitwise the same. The loop
    flips sample t when its dot product with sample t - 1 as flipped is negative; that dot is
    the unflipped one, d_t, times t - 1's sign. So a negative d_t flips t relative to t - 1,
    a positive one keeps t - 1's sign, and a zero (or NaN) one leaves t unflipped: the signs
    are the running parity of negative dots since the last such restart."""
    q = np.moveaxis(np.array(q, copy=True), axis, 0)
    if q.shape[0] < 2:
        return np.moveaxis(q, 0, axis)
    d = _dot(q[1:], q[:-1])  # (T - 1, ...): the dot of each sample with the one before
    neg = np.concatenate([np.zeros((1,) + d.shape[1:], bool), d < 0])
    reset = np.concatenate([np.ones((1,) + d.shape[1:], bool), ~((d < 0) | (d > 0))])
    parity = np.cumsum(neg, axis=0)
    # The parity at the latest reset at or before each sample (a reset sample is unflipped).
    idx = np.where(reset, np.arange(len(q)).reshape((-1,) + (1,) * (d.ndim - 1)), 0)
    last = np.maximum.accumulate(idx, axis=0)
    base = np.take_along_axis(parity, last, axis=0)
    flip = (parity - base) % 2 == 1
    q[flip] *= -1
    return np.moveaxis(q, 0, axis)


def slerp_pairs(q0: np.ndarray, q1: np.ndarray, w: np.ndarray, lerp_eps: float = 0.01) -> np.ndarray:
    """Elementwise SLERP: one weight per pair, ``w`` broadcastable to ``q0.shape[:-1]``.
    Dot products and norms are summed component by component (:func:`_dot`, in the order of
    numpy's ``(a * b).sum(-1)``, so the bits are those of that form) instead of numpy's slow
    reduction over 4 items: it runs over every frame and joint of a fill."""
    q0 = np.asarray(q0, np.float64)
    q1 = np.asarray(q1, np.float64)
    w = np.asarray(w, np.float64)[..., None]
    dot = _dot(q0, q1)[..., None]
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    near = (1.0 - dot) < lerp_eps
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_t = np.where(near, 1.0, np.sin(theta))
    s0 = np.where(near, 1.0 - w, np.sin((1.0 - w) * theta) / sin_t)
    s1 = np.where(near, w, np.sin(w * theta) / sin_t)
    out = s0 * q0 + s1 * q1
    return out / np.sqrt(_dot(out, out))[..., None]
