"""Rotation conversions on numpy arrays of any leading shape.

Quaternions are scalar-last (x, y, z, w) everywhere in this project: it is scipy's order
and the memory order of USD's ``Vt.QuatfArray``. Conversions go through
``scipy.spatial.transform.Rotation``; the few helpers written here (6D, SLERP on arrays,
continuity) are ones scipy has no batched form for.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.spatial.transform import Rotation

#: A rotation quaternion this short or shorter is no rotation (a zeroed key); other lengths
#: are normalised where motion is read, as a DCC's keys are (the USD reader, rig clips).
QUAT_EPS = 1e-6


def _flat(a: np.ndarray, tail: int) -> tuple[np.ndarray, tuple[int, ...]]:
    a = np.asarray(a)
    lead = a.shape[: a.ndim - tail]
    return a.reshape((-1,) + a.shape[a.ndim - tail :]), lead


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


# Blocks: a fill's arrays are (frames x joints) quaternions, ~86k for 4096 frames, and one
# element-wise formula here is tens of numpy operations, each writing a temporary of that
# size (0.7 MB in float64). Run over the whole array those temporaries do not stay in the
# core's caches and each is fresh memory (page faults); run over blocks of about BLOCK
# elements they do, which made these functions about twice as fast. Every function so
# blocked is element-wise over its leading axes, so a block's bits are the whole array's.
BLOCK = 8192


def _block_slices(lead: tuple[int, ...]):
    """Index tuples covering the leading shape ``lead`` in blocks of about BLOCK elements:
    the trailing axes that fit whole, and steps along the next one."""
    inner, k = 1, len(lead)
    while k > 0 and inner * lead[k - 1] <= BLOCK:
        k -= 1
        inner *= lead[k]
    if k == 0:
        yield ()
        return
    k -= 1
    step = max(1, BLOCK // inner)
    for idx in np.ndindex(*lead[:k]):
        for s in range(0, lead[k], step):
            yield idx + (slice(s, s + step),)


def _blockwise(tails: tuple[int, ...], out_tail: tuple[int, ...]):
    """Run an element-wise function of arrays (with ``tails`` trailing component axes each,
    leading axes broadcasting) over blocks of the leading shape (see BLOCK), into one
    float64 result (..., *out_tail); ``out=`` gives that result's array (may be a view)."""

    def deco(fn):
        @functools.wraps(fn)
        def run(*args, out=None, **kw):
            arrays, rest = [np.asarray(a) for a in args[: len(tails)]], args[len(tails) :]
            lead = np.broadcast_shapes(*(a.shape[: a.ndim - t] for a, t in zip(arrays, tails, strict=True)))
            if out is None and math.prod(lead) <= 2 * BLOCK:
                return fn(*arrays, *rest, **kw)
            full = [
                np.broadcast_to(a, lead + a.shape[a.ndim - t :]) for a, t in zip(arrays, tails, strict=True)
            ]
            if out is None:
                out = np.empty(lead + out_tail)
            for sl in _block_slices(lead):
                out[sl] = fn(*(a[sl] for a in full), *rest, **kw)
            return out

        return run

    return deco


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot products over the last axis, summed left to right as numpy's ``(a * b).sum(-1)``
    sums a short axis (so bitwise the same), without its slow reduction over 3 or 4 items."""
    out = a[..., 0] * b[..., 0]
    for i in range(1, a.shape[-1]):
        out += a[..., i] * b[..., i]
    return out


@_blockwise((1,), (4,))
def batch_quat_normalize(q: np.ndarray) -> np.ndarray:
    """q / |q| in float64, as scipy's ``Rotation.from_quat`` normalises."""
    q = np.asarray(q, np.float64)
    return q / np.sqrt(_dot(q, q))[..., None]


@_blockwise((1, 1), (4,))
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


@_blockwise((1, 1), (3,))
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


@_blockwise((1,), (3,))
def batch_quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vectors of unit quaternions (..., 4) -> (..., 3), as scipy's ``as_rotvec``
    (the w >= 0 cover, a Taylor series below 1e-3 rad)."""
    q = np.asarray(q, np.float64)
    q = np.where(q[..., 3:] < 0, -q, q)
    u = q[..., :3]
    angle = 2 * np.arctan2(np.sqrt(_dot(u, u)), q[..., 3])
    small = angle <= 1e-3
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = angle / np.sin(angle / 2)
    if small.any():  # (the series only where some angle needs it: the same selection)
        a2 = angle * angle
        scale = np.where(small, 2 + a2 / 12 + 7 * a2 * a2 / 2880, scale)
    return scale[..., None] * u


@_blockwise((1,), (4,))
def batch_rotvec_to_quat(rv: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) of rotation vectors (..., 3), as scipy's ``from_rotvec``."""
    rv = np.asarray(rv, np.float64)
    angle = np.sqrt(_dot(rv, rv))
    small = angle <= 1e-3
    half = angle / 2
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.sin(half)
        scale /= angle
    if small.any():  # (the series only where some angle needs it: the same selection)
        a2 = angle * angle
        scale = np.where(small, 0.5 - a2 / 48 + a2 * a2 / 3840, scale)
    out = np.empty(rv.shape[:-1] + (4,))
    np.multiply(rv, scale[..., None], out=out[..., :3])
    np.cos(half, out=out[..., 3])
    return out


@_blockwise((1,), (3, 3))
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


@_blockwise((1,), (6,))
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


def _matrix_case(c: int, m00, m01, m02, m10, m11, m12, m20, m21, m22, t):
    """scipy's ``from_matrix`` formula ``c`` (0-2: that diagonal entry is the largest, 3: the
    trace): the quaternion (x, y, z, w) before normalisation."""
    if c == 0:
        return 1 - t + 2 * m00, m10 + m01, m20 + m02, m21 - m12
    if c == 1:
        return m10 + m01, 1 - t + 2 * m11, m21 + m12, m02 - m20
    if c == 2:
        return m20 + m02, m21 + m12, 1 - t + 2 * m22, m10 - m01
    return m21 - m12, m02 - m20, m10 - m01, 1 + t


def _quat_of_matrix_entries(*m):
    """Unit quaternion components (x, y, z, w) of rotation matrices given entry by entry
    (nine arrays of one shape: m00, m01, ..., m22), by scipy's ``from_matrix`` case analysis:
    the largest of the diagonal and the trace picks the formula (the first on ties), then
    q / |q|.

    The most common case is computed on every row, without a gather (on a block of one
    joint's frames, usually the only case: the trace's for rotations under about 120
    degrees, a diagonal's for a joint turned about half a turn); only the rows of other
    cases are gathered and computed again. Each row gets the same element-wise arithmetic as
    one case analysis over all rows, so the bits are those of that form."""
    m00, m11, m22 = m[0], m[4], m[8]
    tr = m00 + m11
    tr += m22
    if ((tr > m00) & (tr > m11) & (tr > m22)).all():  # (a NaN is never the trace's case)
        main, choice = 3, None
    else:
        choice = np.argmax(np.stack([m00, m11, m22, tr], -1), axis=-1)
        count = np.bincount(choice.ravel(), minlength=4)
        main = int(np.argmax(count))
    x, y, z, w = (np.asarray(a, np.float64) for a in _matrix_case(main, *m, tr))  # (fresh arrays)
    if choice is not None:
        for c in np.flatnonzero(count):
            if c == main:
                continue
            rows = choice == c
            for comp, val in zip((x, y, z, w), _matrix_case(c, *(a[rows] for a in m), tr[rows]), strict=True):
                comp[rows] = val
    n = x * x
    n += y * y
    n += z * z
    n += w * w
    np.sqrt(n, out=n)
    return x / n, y / n, z / n, w / n


@_blockwise((2,), (4,))
def batch_matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) of rotation matrices (..., 3, 3) that are orthonormal (to
    1e-12, as Gram–Schmidt's are), by the case analysis scipy's ``from_matrix`` uses (the
    largest of the diagonal and the trace picks the formula, so the same sign comes out).
    Not for matrices that scipy would first orthogonalise by SVD or reject (det <= 0)."""
    m = np.asarray(m, np.float64)
    lead = m.shape[:-2]
    f = m.reshape(-1, 9)
    comps = _quat_of_matrix_entries(*(f[:, i] for i in range(9)))
    q = np.empty((len(f), 4))
    for i, c in enumerate(comps):
        q[:, i] = c
    return q.reshape(lead + (4,))


def batch_sixd_to_quat(d6: np.ndarray, axis: int = -1, out: np.ndarray | None = None) -> np.ndarray:
    """Unit quaternions (..., 4) of 6D rotations with their six components along ``axis``:
    ``batch_matrix_to_quat(batch_sixd_to_matrix(d6))`` bitwise, without the 3x3 matrices in
    between. It decodes every frame and joint a network predicts, so ``axis`` may be the
    network's channel axis (each component then one contiguous row of frames), and ``out``
    (..., 4) may be a view of another layout to write to.

    With the components on the second-to-last axis (..., 6, N), the rows are decoded as they
    lie, a block of frames of the six rows at a time (contiguous rows, not strided columns:
    the same arithmetic on each element)."""
    d6 = np.asarray(d6)
    if d6.ndim >= 2 and axis in (-2, d6.ndim - 2) and d6.shape[-2] == 6:
        lead, n = d6.shape[:-2], d6.shape[-1]
        if out is None:
            out = np.empty(lead + (n, 4))
        step = BLOCK
        for idx in np.ndindex(*lead):
            rows, dst = d6[idx], out[idx]
            for s in range(0, n, step):
                comps = _sixd_rows_to_quat(*rows[:, s : s + step].astype(np.float64))
                for i, comp in enumerate(comps):
                    dst[s : s + step, i] = comp
        return out
    return _sixd_to_quat(np.moveaxis(d6, axis, -1), out=out)


def _sixd_rows_to_quat(a1x, a1y, a1z, a2x, a2y, a2z):
    """Quaternion components (x, y, z, w) of 6D rotations given component by component
    (float64 arrays of one shape): Gram–Schmidt, the third column, scipy's case analysis."""
    n = a1x * a1x
    n += a1y * a1y
    n += a1z * a1z
    np.sqrt(n, out=n)
    b1x, b1y, b1z = a1x / n, a1y / n, a1z / n
    d = b1x * a2x
    d += b1y * a2y
    d += b1z * a2z
    b2x, b2y, b2z = a2x - d * b1x, a2y - d * b1y, a2z - d * b1z
    n = b2x * b2x
    n += b2y * b2y
    n += b2z * b2z
    np.sqrt(n, out=n)
    b2x /= n
    b2y /= n
    b2z /= n
    m02 = b1y * b2z - b1z * b2y
    m12 = b1z * b2x - b1x * b2z
    m22 = b1x * b2y - b1y * b2x
    return _quat_of_matrix_entries(b1x, b2x, m02, b1y, b2y, m12, b1z, b2z, m22)


@_blockwise((1,), (4,))
def _sixd_to_quat(d6: np.ndarray) -> np.ndarray:
    c = np.moveaxis(np.asarray(d6, np.float64), -1, 0)
    comps = _sixd_rows_to_quat(*c)
    q = np.empty((4,) + c.shape[1:])
    for i, comp in enumerate(comps):
        q[i] = comp
    return np.moveaxis(q, 0, -1)


def batch_quat_continuity(q: np.ndarray, axis: int = 0, copy: bool = True) -> np.ndarray:
    """:func:`quat_continuity` without its loop over samples, bitwise the same. The loop
    flips sample t when its dot product with sample t - 1 as flipped is negative; that dot is
    the unflipped one, d_t, times t - 1's sign. So a negative d_t flips t relative to t - 1,
    a positive one keeps t - 1's sign, and a zero (or NaN) one leaves t unflipped: the signs
    are the running parity of negative dots since the last such restart. With ``copy``
    False a float array ``q`` is flipped in place (and returned)."""
    q = np.moveaxis(np.array(q, copy=True) if copy else np.asarray(q), axis, 0)
    if q.shape[0] < 2:
        return np.moveaxis(q, 0, axis)
    d = _dot(q[1:], q[:-1])  # (T - 1, ...): the dot of each sample with the one before
    neg = np.empty((len(q),) + d.shape[1:], bool)
    neg[0] = False
    np.less(d, 0, out=neg[1:])
    parity = np.logical_xor.accumulate(neg, axis=0)  # odd count of negative dots so far
    restart = ~((d < 0) | (d > 0))  # (a zero or NaN dot: sample t + 1 unflipped)
    if restart.any():
        reset = np.concatenate([np.ones((1,) + d.shape[1:], bool), restart])
        # The parity at the latest reset at or before each sample (a reset sample is unflipped).
        idx = np.where(reset, np.arange(len(q)).reshape((-1,) + (1,) * (d.ndim - 1)), 0)
        last = np.maximum.accumulate(idx, axis=0)
        parity ^= np.take_along_axis(parity, last, axis=0)
    np.negative(q, out=q, where=parity[..., None])
    return np.moveaxis(q, 0, axis)


def _slerp_terms(q0: np.ndarray, q1: np.ndarray, lerp_eps: float):
    """What SLERP between q0 and q1 needs besides the weight: q1 on q0's hemisphere, whether
    the pair is near enough to LERP, the angle between them and its sine (1 where LERP)."""
    dot = _dot(q0, q1)[..., None]
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    near = (1.0 - dot) < lerp_eps
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    return q1, near, theta, np.where(near, 1.0, np.sin(theta))


@_blockwise((1, 1, 0), (4,))
def slerp_pairs(q0: np.ndarray, q1: np.ndarray, w: np.ndarray, lerp_eps: float = 0.01) -> np.ndarray:
    """Elementwise SLERP: one weight per pair, ``w`` broadcastable to ``q0.shape[:-1]``.
    Dot products and norms are summed component by component (:func:`_dot`, in the order of
    numpy's ``(a * b).sum(-1)``, so the bits are those of that form) instead of numpy's slow
    reduction over 4 items: it runs over every frame and joint of a fill."""
    q0 = np.asarray(q0, np.float64)
    q1 = np.asarray(q1, np.float64)
    w = np.asarray(w, np.float64)[..., None]
    q1, near, theta, sin_t = _slerp_terms(q0, q1, lerp_eps)
    s0 = np.where(near, 1.0 - w, np.sin((1.0 - w) * theta) / sin_t)
    s1 = np.where(near, w, np.sin(w * theta) / sin_t)
    out = s0 * q0 + s1 * q1
    return out / np.sqrt(_dot(out, out))[..., None]


def slerp_frames(
    q: np.ndarray, i0: np.ndarray, i1: np.ndarray, w: np.ndarray, lerp_eps: float = 0.01
) -> np.ndarray:
    """SLERP between frames of one array: (B, N', ..., 4) from q (B, N, ..., 4), frame t
    between frames ``i0[t]`` and ``i1[t]`` at weight ``w[t]`` (all (N',)). Bitwise
    ``slerp_pairs(q[:, i0], q[:, i1], w[None, :, None...])``, but the terms of a pair of
    frames (the dot product, the sign flip, the angle and its sine) are computed once per
    distinct pair, not once per frame: between keys every frame of a gap shares its pair.
    The frames then run in blocks (see BLOCK), gathering their pair's terms."""
    q = np.asarray(q, np.float64)
    i0, i1 = np.asarray(i0, np.int64), np.asarray(i1, np.int64)
    w = np.asarray(w, np.float64)
    pairs, inv = np.unique(i0 * q.shape[1] + i1, return_inverse=True)
    q0 = q[:, pairs // q.shape[1]]
    q1, near, theta, sin_t = _slerp_terms(q0, q[:, pairs % q.shape[1]], lerp_eps)
    out = np.empty((len(q), len(i0)) + q.shape[2:])
    tail = (1,) * (q.ndim - 2)
    step = max(1, BLOCK // max(1, math.prod(q.shape[2:-1]) * len(q)))
    for s in range(0, len(i0), step):
        at = inv[s : s + step]
        wb = w[s : s + step].reshape((1, -1) + tail)
        nb, tb, sb = near[:, at], theta[:, at], sin_t[:, at]
        s0 = np.where(nb, 1.0 - wb, np.sin((1.0 - wb) * tb) / sb)
        s1 = np.where(nb, wb, np.sin(wb * tb) / sb)
        o = s0 * q0[:, at]
        o += s1 * q1[:, at]
        o /= np.sqrt(_dot(o, o))[..., None]
        out[:, s : s + step] = o
    return out
