"""Post-processing after the networks: keys exact, root through every key, foot contacts locked.

All in numpy, on motions of the model skeleton. Quaternion products, rotations of vectors,
rotation vectors and FK are batched float64 array arithmetic (``batch_*`` in
``pipeline.motion.rotations``, ``pipeline.motion.fk``): a scipy ``Rotation`` built per call
cost more than the arithmetic on these small arrays; the average of a contact's foot
orientations and the slerp along held keys are written out the same way (:func:`_mean_rotation`,
:func:`_slerp_keys`).
- :func:`match_keys` — the residual at each key (rotation vector per joint, vector for the
  root) is spread over the frames between neighbouring keys with smoothstep weights, so key
  frames equal the input exactly and the correction has zero velocity at keys (no pop).
- The same correction makes the root path pass through every key's root position, with the
  drift spread over each gap rather than dumped on its last frame.
- :func:`lock_feet` — frames predicted in contact pull the ankle to the contact's mean
  position with a two-bone IK (hip, knee) blended in and out; bone lengths are untouched
  (only rotations change) and key frames are left exact.
"""

from __future__ import annotations

import numpy as np

from pipeline.infer.features import key_groups
from pipeline.motion.fk import fk
from pipeline.motion.rotations import (
    BLOCK,
    batch_quat_apply,
    batch_quat_conj,
    batch_quat_continuity,
    batch_quat_mul,
    batch_quat_normalize,
    batch_quat_to_rotvec,
    batch_rotvec_to_quat,
)


def _smoothstep(x):
    return x * x * (3 - 2 * x)


def key_weights(n: int, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each frame: the position in ``keys`` of the previous and of the next key, and the
    smoothstep weight of the next key."""
    from pipeline.infer.features import key_neighbours

    prev, nxt = key_neighbours(n, keys)
    span = np.maximum(nxt - prev, 1)
    s = np.where(nxt > prev, (np.arange(n) - prev) / span, 0.0)
    return np.searchsorted(keys, prev), np.searchsorted(keys, nxt), _smoothstep(s)


def match_keys(rot, root, key_rot, key_root, keys, joint_keys=None):
    """Make frames ``keys`` equal the given key values; spread the corrections smoothly.

    ``rot`` (B, N, J, 4), ``root`` (B, N, 3); ``key_rot`` (B, K, J, 4), ``key_root`` (B, K, 3).
    Frames before the first key and after the last hold those keys. With ``joint_keys``
    (K, J + 1; the first and last keys full) each joint and the root match only the keys that
    key them, and their corrections spread between those.
    """
    # Long because it is one vectorised kernel: the per-key correction and its spreading share
    # one key indexing; partial keys only select which channels each key corrects.
    B, N, J = rot.shape[:3]
    keys = np.asarray(keys)
    K = len(keys)
    mask = np.ones((K, J + 1), bool) if joint_keys is None else np.asarray(joint_keys, bool)
    # Residual rotation r with r · pred = key, as a rotation vector (world-from-local side).
    # (Inputs normalised first, as scipy's Rotation did.)
    inv = batch_quat_conj(batch_quat_normalize(rot[:, keys]))
    delta = batch_quat_mul(batch_quat_normalize(key_rot), inv)
    rv = batch_quat_to_rotvec(batch_quat_normalize(delta))
    dr = key_root.astype(np.float64) - root[:, keys]
    corr = spread = None
    out_root = np.asarray(root, np.float64).copy()
    for at, cols in key_groups(mask):
        ip, inx, s = key_weights(N, keys[at])
        ip, inx = at[ip], at[inx]
        joints = cols[cols < J]
        w = s[None, :, None, None]
        if len(joints) == J:  # every joint (the usual case): the correction is made in blocks
            spread = ip, inx, w
        elif len(joints):
            corr = np.empty((B, N, J, 3)) if corr is None else corr
            corr[:, :, joints] = (1 - w) * rv[:, ip][:, :, joints] + w * rv[:, inx][:, :, joints]
        if J in cols:
            out_root = out_root + (1 - s)[None, :, None] * dr[:, ip] + s[None, :, None] * dr[:, inx]
    # The corrected rotations over blocks of frames: the correction's rotation vectors, their
    # quaternions and the product, element-wise as over the whole shot, in the cache.
    out_rot = np.empty((B, N, J, 4))
    step = max(1, BLOCK // (B * J))
    for f0 in range(0, N, step):
        f = slice(f0, f0 + step)
        if spread is not None:
            ip, inx, w = spread
            c = (1 - w[:, f]) * rv[:, ip[f]] + w[:, f] * rv[:, inx[f]]
        else:
            c = corr[:, f]
        out_rot[:, f] = batch_quat_mul(batch_rotvec_to_quat(c), batch_quat_normalize(rot[:, f]))

    unique = len(np.unique(keys)) == K
    full = bool(mask[:, :J].all())

    def put_keys(out_rot):
        # Keys bitwise: the inputs' own values, not a round trip through rotation vectors.
        if unique and full:  # (every joint keyed at every key: the keys' values as they are)
            out_rot[:, keys] = key_rot
            return
        if unique:  # (all at once; with a key given twice the last one wins, as in the loop)
            out_rot[:, keys] = np.where(mask[None, :, :J, None], key_rot, out_rot[:, keys])
            return
        for i, k in enumerate(keys):
            out_rot[:, k, mask[i, :J]] = key_rot[:, i, mask[i, :J]]

    put_keys(out_rot)
    out_root[:, keys[mask[:, J]]] = key_root[:, mask[:, J]]
    out_rot[:, : keys[0]] = key_rot[:, :1]
    out_root[:, : keys[0]] = key_root[:, :1]
    out_rot[:, keys[-1] + 1 :] = key_rot[:, -1:]
    out_root[:, keys[-1] + 1 :] = key_root[:, -1:]
    out_rot = batch_quat_continuity(out_rot, axis=1, copy=False)
    put_keys(out_rot)  # continuity may have flipped a key's sign; keep its value
    return out_rot.astype(np.float32), out_root.astype(np.float32)


def contact_segments(flags: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) runs of True."""
    d = np.diff(np.r_[0, flags.astype(np.int8), 0])
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True))


def _rot_between(u, v):
    """Minimal rotations taking directions u to v, (N, 3) -> unit quaternions (N, 4)."""
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    v = v / np.linalg.norm(v, axis=-1, keepdims=True)
    axis = np.cross(u, v)
    s = np.linalg.norm(axis, axis=-1, keepdims=True)
    c = (u * v).sum(-1, keepdims=True)
    ang = np.arctan2(s, c)
    axis = np.where(s > 1e-9, axis / np.maximum(s, 1e-12), 0.0)
    return batch_rotvec_to_quat(axis * ang)


def two_bone_ik(rot, root, skeleton, leg, targets, weight, orient=None, posed=None):
    """Move the ankle of ``leg`` = (hip, knee, ankle, toe) toward ``targets`` (N, 3) by ``weight`` (N,).

    Changes the local rotations of hip, knee and ankle only, so bone lengths never change;
    joints between them in the chain (a rig's roll joints) keep theirs and turn with it.
    The ankle keeps its world orientation, or with ``orient`` (N, 4 world quaternions) turns
    toward it by the same weight. ``rot`` (N, J, 4) local, ``root`` (N, 3). ``posed``: the
    caller's FK of ``rot`` (global rotations, positions over all N frames, float64) where it
    has it for the ankle and its ancestors; otherwise it is computed here.
    """
    hip, knee, ankle, _ = leg
    sel = weight > 1e-4
    if not sel.any():
        return rot
    rot = rot.copy()
    parent = skeleton.parents[hip]
    if posed is None:
        gq, gp = fk(
            rot[sel].astype(np.float64), root[sel], skeleton.parents, skeleton.offsets, joints=[ankle]
        )
    else:
        gq, gp = posed[0][sel], posed[1][sel]
    a, b, c = gp[:, hip], gp[:, knee], gp[:, ankle]
    t = c + weight[sel, None] * (targets[sel] - c)
    lab = np.linalg.norm(b - a, axis=-1)
    lcb = np.linalg.norm(c - b, axis=-1)
    # A leg already straighter than the bound keeps its reach: clipping it would bend the knee.
    reach = np.maximum((lab + lcb) * 0.999, np.linalg.norm(c - a, axis=-1))
    lat = np.clip(np.linalg.norm(t - a, axis=-1), 1e-3, reach)
    # Knee: set the interior angle so that hip–ankle distance equals hip–target distance.
    cos_now = ((a - b) * (c - b)).sum(-1) / (lab * lcb)
    cos_want = (lab**2 + lcb**2 - lat**2) / (2 * lab * lcb)
    dtheta = np.arccos(np.clip(cos_want, -1, 1)) - np.arccos(np.clip(cos_now, -1, 1))
    n = np.cross(a - b, c - b)
    n_norm = np.linalg.norm(n, axis=-1, keepdims=True)
    # A straight leg has no bend plane: bend forward around the hip's local X as a fallback.
    q_parent, q_hip, q_knee, q_ankle = (batch_quat_normalize(gq[:, j]) for j in (parent, hip, knee, ankle))
    fallback = batch_quat_apply(q_hip, np.array([1.0, 0, 0]))
    n = np.where(n_norm > 1e-6, n / np.maximum(n_norm, 1e-12), fallback)
    # Rotating c about the knee by +angle around n opens the interior angle.
    r_knee = batch_rotvec_to_quat(n * dtheta[:, None])
    c1 = b + batch_quat_apply(r_knee, c - b)
    r_hip = _rot_between(c1 - a, t - a)
    g_hip = batch_quat_mul(r_hip, q_hip)
    g_knee = batch_quat_mul(batch_quat_mul(r_hip, r_knee), q_knee)
    g_ankle = q_ankle
    if orient is not None:
        # Per-frame slerp from the network's foot orientation to the held one.
        delta = batch_quat_to_rotvec(
            batch_quat_mul(batch_quat_conj(g_ankle), batch_quat_normalize(orient[sel]))
        )
        g_ankle = batch_quat_mul(g_ankle, batch_rotvec_to_quat(delta * weight[sel, None]))
    rot[sel, hip] = batch_quat_mul(batch_quat_conj(q_parent), g_hip)
    above_knee = _turned_parent(gq, skeleton, knee, hip, g_hip, r_hip)
    above_ankle = _turned_parent(gq, skeleton, ankle, knee, g_knee, batch_quat_mul(r_hip, r_knee))
    rot[sel, knee] = batch_quat_mul(batch_quat_conj(above_knee), g_knee)
    rot[sel, ankle] = batch_quat_mul(batch_quat_conj(above_ankle), g_ankle)
    return rot


def _turned_parent(gq, skeleton, joint: int, above: int, g_above, turn):
    """World rotation of ``joint``'s parent as the IK leaves it: ``g_above`` when the parent is
    ``above`` (the hip or the knee), else the parent's own (a rig's roll or twist joint in the
    chain, its local rotation kept) turned with the leg by ``turn``."""
    parent = skeleton.parents[joint]
    return g_above if parent == above else batch_quat_mul(turn, batch_quat_normalize(gq[:, parent]))


# The held foot orientations: scipy's ``Slerp`` and ``Rotation.mean`` did these, one pair of
# Rotation objects per contact; on a contact's few frames the objects' set-up and checks
# cost more than the arithmetic, so they are written out on arrays here (the same formulas:
# equal to scipy's to ~1e-16, so a fill moves by at most a float32 rounding).


def _slerp_keys(q: np.ndarray, times: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Unit quaternions (len(at), 4) of key rotations ``q`` (K, 4) at sorted ``times`` (K,),
    interpolated at ``at`` (within the times), as ``scipy...Slerp(times, q)(at).as_quat()``:
    from each key, its rotation vector to the next scaled by the time since."""
    q = batch_quat_normalize(q)
    if len(q) == 1:
        return np.repeat(q, len(at), 0)
    step = batch_quat_to_rotvec(batch_quat_mul(batch_quat_conj(q[:-1]), q[1:]))
    i = np.searchsorted(times, at) - 1
    i[at == times[0]] = 0
    alpha = (at - times[i]) / np.diff(times)[i]
    return batch_quat_mul(q[i], batch_rotvec_to_quat(step[i] * alpha[:, None]))


def _mean_rotation(q: np.ndarray) -> np.ndarray:
    """The mean rotation (4,) of unit quaternions (n, 4), as scipy's ``Rotation.mean()``: the
    eigenvector of the largest eigenvalue of the mean of q q^T (either sign: the same
    rotation, and two_bone_ik takes the shorter turn to it either way)."""
    q = batch_quat_normalize(q)
    return np.linalg.eigh(q.T @ q / len(q))[1][:, -1]


def lock_feet(
    rot,
    root,
    skeleton,
    contacts,
    keys,
    legs,
    ramp: int = 4,
    anchor: bool = False,
    orient: bool = False,
    height: bool = False,
):
    """Two-bone IK on frames in contact (``contacts`` (N, 2): per leg), blended over ``ramp`` frames.

    A contact is locked at its mean ankle position. Key frames get weight 0 and the weight
    rises over ``ramp`` frames away from them; frames before the first key and after the last
    are held, so they get no IK either. With ``anchor``, a contact that holds a key is locked
    at that key's own ankle position (between two such keys, their line) at full weight up to
    the key: the foot the animator planted stays planted, even in gaps shorter than the ramp.
    With ``orient`` the foot's world orientation is held too (the key's, slerped between two
    such keys, else the contact's mean), so the toes stay put while the ankle is locked. With
    ``height`` (and ``anchor``) the ankle's height follows the held keys' line too, not only
    its place on the ground.
    """
    # Long because it is one vectorised kernel: per leg, the contact segments, their targets
    # and the ramp weights feed one IK call; apart, each step would need all the others' arrays.
    N = len(rot)
    keys = np.asarray(keys)
    ankles = [leg[2] for leg in legs]
    gq, gp = fk(rot.astype(np.float64), root, skeleton.parents, skeleton.offsets, joints=ankles)
    # Frames to the nearest key (the keys on either side of each frame; keys sorted).
    order = np.sort(keys)
    at = np.searchsorted(order, np.arange(N))
    dist_key = np.minimum(
        np.abs(np.arange(N) - order[np.clip(at, 0, len(order) - 1)]),
        np.abs(np.arange(N) - order[np.clip(at - 1, 0, len(order) - 1)]),
    )
    key_fade = np.clip(dist_key / ramp, 0, 1)
    outside = np.zeros(N, bool)
    outside[: keys[0]] = True
    outside[keys[-1] + 1 :] = True
    out = rot.copy()
    moved: set[int] = set()  # joints an earlier leg's IK changed
    for li, leg in enumerate(legs):
        ankle = leg[2]
        weight = np.zeros(N)
        fade = key_fade.copy()
        targets = gp[:, ankle].copy()
        turn = gq[:, ankle].copy() if orient else None
        for s0, s1 in contact_segments(contacts[:, li] > 0.5):
            if s1 - s0 < 2:
                continue
            frames = np.arange(s0, s1)
            held = keys[(keys >= s0) & (keys < s1)] if anchor else keys[:0]
            ramp_in = np.clip((frames - s0 + 1) / ramp, 0, 1)
            ramp_out = np.clip((s1 - frames) / ramp, 0, 1)
            if len(held):
                for axis in (0, 1, 2) if height else (0, 2):
                    targets[s0:s1, axis] = np.interp(frames, held, gp[held, ankle, axis])
                # The key's own position is the target there: no fade needed toward the key.
                fade[s0:s1] = 1.0
                ramp_in[frames >= held[0]] = 1.0
                ramp_out[frames <= held[-1]] = 1.0
                if orient:
                    turn[s0:s1] = _slerp_keys(gq[held, ankle], held, np.clip(frames, held[0], held[-1]))
            else:
                lock = gp[s0:s1, ankle].mean(0)
                targets[s0:s1, 0] = lock[0]
                targets[s0:s1, 2] = lock[2]
                if orient:
                    turn[s0:s1] = _mean_rotation(gq[s0:s1, ankle])
            weight[s0:s1] = _smoothstep(np.minimum(ramp_in, ramp_out))
        fade[keys[(keys >= 0) & (keys < N)]] = 0.0  # callers may pass keys outside the clip
        fade[outside] = 0.0
        weight *= _smoothstep(fade)
        # The FK above still holds for this leg unless an earlier leg's IK moved one of its
        # ankle's ancestors (FK is frame by frame, so it is the same as FK of those frames).
        chain, j = set(), ankle
        while j >= 0:
            chain.add(j)
            j = skeleton.parents[j]
        posed = None if chain & moved else (gq, gp)
        out = two_bone_ik(out, root, skeleton, leg, targets, weight, turn, posed)
        moved.update(leg[:3])
    return out.astype(np.float32)
