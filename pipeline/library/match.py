"""Searching a library for the stretch of motion between two keys, and fitting it onto them.

For a gap from key a to key b, ``n`` frames apart, every library frame ``s`` whose take runs
on to ``s + n`` is a candidate window. Its cost, in cm:

- the pose miss at both ends: the root-mean-square joint-position miss between frame ``s``
  and key a, and between ``s + n`` and key b (:mod:`pipeline.library.match_features`: facing and
  place do not count, posture and root height do);
- the root's travel: how far the window's root displacement over the gap, seen from its first
  frame's facing, misses the keys' (``DISP_WEIGHT`` per cm), and its change of facing the
  keys' (``TURN_WEIGHT`` cm per radian).

The pose terms of every frame come from one matrix product per block of keys (the distances
of every key to every library frame, :func:`key_distances`); the travel terms are computed for
the ``PREFILTER`` windows of least pose miss only. The ``best`` windows of least cost are then
fitted (:func:`fit_window`): turned about the vertical and moved so that their first frame
faces and stands where key a does, the root's miss at key b spread linearly over the gap, and
each joint's rotation offset to the keys (key ⊗ window⁻¹, at both ends) slerped across the gap
and applied, so the fit passes through both keys; the fitted windows are averaged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.library.store import DAMAGED, LibraryError, damage, sqnorm_damage
from pipeline.motion.rotations import (
    batch_quat_apply,
    batch_quat_conj,
    batch_quat_mul,
    batch_quat_normalize,
    slerp_pairs,
)

# DAMAGED (pipeline.library.store): what a library array that is not finite numbers says,
# checked where the search reads it, not on opening: that would read every frame of a
# 10-hour library for each fill (`tween library info` does, pipeline.library.store.verify).
#: Windows fitted and averaged per gap.
BEST = 8
#: Windows of least pose miss whose travel terms are computed.
PREFILTER = 256
#: Cost (cm) per cm that a window's root displacement misses the keys'.
DISP_WEIGHT = 0.5
#: Cost (cm) per radian that a window's change of facing misses the keys'.
TURN_WEIGHT = 20.0
#: Weight of each key beside the gap (its squared pose miss) against the gap's own two.
CONTEXT_WEIGHT = 0.25
#: Keys beside a gap further than this (frames) from it give no context.
CONTEXT_FRAMES = 60
#: Cost (cm) over the best window's at which a window counts 1/e as much in the average
#: (None: every window alike).
SOFTMIN_CM = 2.0
#: Library frames whose distances to the keys are computed at once.
FRAME_BLOCK = 65536
#: The coarse pass looks at every STRIDE-th window start.
STRIDE = 3
#: Keys whose distances to every library frame are held at once (memory: KEY_BLOCK × frames
#: float32; 138 MB for a 10-hour library at 30 fps).
KEY_BLOCK = 32


@dataclass
class GapMatch:
    """The windows chosen for one gap: their first library frames, costs and pose misses
    (cm), and their weights in the average."""

    starts: np.ndarray
    cost: np.ndarray
    pose_cm: np.ndarray
    weights: np.ndarray

    @property
    def miss_cm(self) -> float:
        """The chosen windows' weighted pose miss at the two keys (cm): how like the keys the
        library's motion is."""
        return float(np.dot(self.weights, self.pose_cm))


def key_distances(lib, feats: np.ndarray) -> np.ndarray:
    """(K, F) float32: each key's mean squared joint-position miss (cm²) against every
    library frame, for K key features (K, D); one row a key, so that a key's row is
    contiguous (the search reads it in strides). Computed in blocks of frames (the product
    in its fast (frames, keys) layout, then turned), so memory is the result's."""
    joints = (feats.shape[1] - 1) / 3.0
    k = np.asarray(feats, np.float32)
    k2 = -2.0 * k.T
    kk = (k * k).sum(1)
    out = np.empty((len(k), lib.frames), np.float32)
    # Damaged numbers overflow or are NaN here: the check below names the file, numpy is quiet.
    with np.errstate(over="ignore", invalid="ignore"):
        for s in range(0, lib.frames, FRAME_BLOCK):
            d = lib.features[s : s + FRAME_BLOCK] @ k2
            d += lib.sqnorm[s : s + FRAME_BLOCK, None]
            d += kk[None]
            np.maximum(d, 0.0, out=d)
            out[:, s : s + FRAME_BLOCK] = d.T
        out /= joints
    if not np.isfinite(out).all():  # else those frames would drop out of every search unsaid
        raise LibraryError(f"{lib.folder / 'features.bin'}: {DAMAGED}")
    return out


def yaw_of(q: np.ndarray) -> np.ndarray:
    """The angle (rad) of yaw quaternions about +Y."""
    return 2.0 * np.arctan2(q[..., 1], q[..., 3])


def wrap_angle(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def _strided(a: np.ndarray, start: int, count: int, step: int) -> np.ndarray:
    """``a[start + step * i]`` for i < count, a view where it can be (0 where out of range)."""
    stop = start + step * count
    if start >= 0 and stop - step < len(a):
        return a[start:stop:step]
    out = np.zeros(count, a.dtype)
    i0 = max(0, -(start // step) if start < 0 else 0)
    while start + step * i0 < 0:
        i0 += 1
    i1 = min(count, (len(a) - 1 - start) // step + 1)
    if i1 > i0:
        out[i0:i1] = a[start + step * i0 : start + step * (i1 - 1) + 1 : step]
    return out


def _pose_terms(lib, d_a, d_b, n: int, context, at) -> np.ndarray:
    """The pose part of the cost (cm², summed) of the windows starting at frames ``at`` (an
    index array, or a ``slice`` with a step: read as strided views, not gathered), inf where
    the take ends before ``at + n``. A context key whose offset falls outside the window's
    take counts as the gap's own keys do on average (no evidence either way)."""
    if isinstance(at, slice):
        count = len(range(at.start, at.stop, at.step))

        def read(a, shift=0):
            return _strided(a, at.start + shift, count, at.step)
    else:

        def read(a, shift=0):
            return a.take(at + shift, mode="clip")

    left = read(lib.frames_left)
    own = read(d_a) + read(d_b, n)
    pose = own.copy()
    for d_c, off in context if CONTEXT_WEIGHT else ():
        inside = left >= off if off > 0 else read(lib.frames_before) >= -off
        pose += CONTEXT_WEIGHT * np.where(inside, read(d_c, off), 0.5 * own)
    pose[left < n] = np.inf
    return pose


def search(lib, d_a: np.ndarray, d_b: np.ndarray, n: int, travel: np.ndarray, turn: float,
           best: int = BEST, context=()) -> GapMatch | None:  # fmt: skip
    """The ``best`` windows for a gap of ``n`` frames whose keys' distances to every library
    frame are ``d_a`` and ``d_b`` (F,), whose root travels ``travel`` (x, z, seen from key a's
    facing) and turns ``turn`` rad. ``context``: (distances (F,), offset) of the keys beside
    the gap, ``offset`` frames from key a: a window whose take around it also passes near
    them (a walk in the same phase, a jump with the same run-up) costs less
    (``CONTEXT_WEIGHT``). None when no take is long enough.

    Coarse to fine: the pose terms of every ``STRIDE``-th start first (motion at 30 fps
    changes little from one frame to the next), then every start around the best of those."""
    F = lib.frames
    if n < 1 or n >= F:
        return None
    pose = _pose_terms(lib, d_a, d_b, n, context, slice(0, F - n, STRIDE))
    p = min(PREFILTER, len(pose))
    top = (np.argpartition(pose, p - 1)[:p] if p < len(pose) else np.arange(len(pose))) * STRIDE
    near = np.unique((top[:, None] + np.arange(-(STRIDE // 2), STRIDE - STRIDE // 2)).ravel())
    near = near[(near >= 0) & (near < F - n)]
    pose = _pose_terms(lib, d_a, d_b, n, context, near)
    keep = np.argsort(pose, kind="stable")[:PREFILTER]
    cand = near[keep][np.isfinite(pose[keep])]
    pose = pose[keep][np.isfinite(pose[keep])]
    if not len(cand):
        return None
    pose_cm = 0.5 * (np.sqrt(d_a[cand]) + np.sqrt(d_b[cand + n]))
    ctx_cm = np.sqrt(pose / 2.0)  # the pose terms with the context keys, as an RMS (cm)
    with np.errstate(over="ignore", invalid="ignore"):  # damaged numbers: named just below
        face = np.asarray(lib.facing[cand], np.float64)
        step = np.asarray(lib.roots[cand + n], np.float64) - lib.roots[cand]
        disp = batch_quat_apply(face, step)[:, [0, 2]]
        lib_turn = wrap_angle(yaw_of(face) - yaw_of(np.asarray(lib.facing[cand + n], np.float64)))
        cost = 2.0 * ctx_cm if context and CONTEXT_WEIGHT else 2.0 * pose_cm
        cost = cost + DISP_WEIGHT * np.linalg.norm(disp - travel, axis=1)
        cost += TURN_WEIGHT * np.abs(wrap_angle(lib_turn - turn))
    if not np.isfinite(cost).all():
        raise LibraryError(f"{lib.folder / 'roots.bin'} or facing.bin: {DAMAGED}")
    _check_ends(lib, np.concatenate([cand, cand + n]))
    order = np.argsort(cost, kind="stable")[:best]
    if SOFTMIN_CM:
        w = np.exp(-(cost[order] - cost[order[0]]) / SOFTMIN_CM)
        w /= w.sum()
    else:
        w = np.full(len(order), 1.0 / len(order))
    return GapMatch(cand[order], cost[order], pose_cm[order], w)


def _check_ends(lib, frames: np.ndarray) -> None:
    """LibraryError naming the file where the candidate windows' end frames hold finite
    numbers no library holds (a facing of another length than 1, features and squared
    lengths that disagree): the cost would take them as it takes any number."""
    why = damage("facing", lib.facing[frames])
    if why:
        raise LibraryError(f"{lib.folder / 'facing.bin'}: {why}")
    why = sqnorm_damage(lib.features[frames], lib.sqnorm[frames])
    if why:
        raise LibraryError(f"{lib.folder / 'features.bin'} or sqnorm.bin: {why}")


def window_contacts(lib, s: int, n: int) -> np.ndarray:
    """(n + 1, 2) float64: the feet's contacts over library frames ``s .. s + n``; LibraryError
    naming contacts.bin where they are not 0 and 1 (each would count as a foot planted)."""
    c = np.asarray(lib.contacts[s : s + n + 1])
    why = damage("contacts", c)
    if why:
        raise LibraryError(f"{lib.folder / 'contacts.bin'}, frames {s}-{s + n}: {why}")
    return c.astype(np.float64)


def fit_window(lib, s: int, n: int, key_rot: np.ndarray, key_root: np.ndarray,
               key_face: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Library frames ``s .. s + n`` fitted onto the keys: (n + 1, J, 4) rotations and
    (n + 1, 3) roots equal to the keys (``key_rot`` (2, J, 4), ``key_root`` (2, 3)) at both
    ends up to rounding. ``key_face``: key a's facing turn (4,)."""
    with np.errstate(invalid="ignore"):  # a damaged file's signalling NaN: named just below
        rot = np.array(lib.rotations[s : s + n + 1], np.float64)
        root = np.array(lib.roots[s : s + n + 1], np.float64)
    if not (np.isfinite(rot).all() and np.isfinite(root).all()):
        raise LibraryError(f"{lib.folder / 'rotations.bin'} or roots.bin, frames {s}-{s + n}: {DAMAGED}")
    why = damage("rotations", rot)
    if why:
        raise LibraryError(f"{lib.folder / 'rotations.bin'}, frames {s}-{s + n}: {why}")
    # Turn the window to face as key a does and stand where it stands.
    align = batch_quat_mul(batch_quat_conj(key_face), np.asarray(lib.facing[s], np.float64))
    rot[:, 0] = batch_quat_mul(np.broadcast_to(align, rot[:, 0].shape), rot[:, 0])
    root = batch_quat_apply(np.broadcast_to(align, root.shape[:1] + (4,)), root - root[0]) + key_root[0]
    t = np.arange(n + 1, dtype=np.float64) / n
    root += t[:, None] * (key_root[1] - root[-1])
    # Each joint's offset to the keys at both ends, slerped across the gap.
    k = np.asarray(key_rot, np.float64)
    o_a = batch_quat_mul(k[0], batch_quat_conj(rot[0]))
    o_b = batch_quat_mul(k[1], batch_quat_conj(rot[-1]))
    off = slerp_pairs(np.broadcast_to(o_a, rot.shape), np.broadcast_to(o_b, rot.shape), t[:, None])
    rot = batch_quat_normalize(batch_quat_mul(off, rot))
    return rot, root


def average(rots: list[np.ndarray], roots: list[np.ndarray], weights: np.ndarray):
    """The weighted mean of fitted windows: rotations on the first's hemisphere, summed and
    normalised; roots averaged."""
    ref = rots[0]
    acc = np.zeros_like(ref)
    for r, w in zip(rots, weights, strict=True):
        sign = np.where((r * ref).sum(-1, keepdims=True) < 0, -1.0, 1.0)
        acc += w * sign * r
    root = sum(w * p for p, w in zip(roots, weights, strict=True))
    return batch_quat_normalize(acc), root
