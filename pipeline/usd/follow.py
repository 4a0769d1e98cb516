"""Kept root controls that follow a character joint: an IK target, a pole, a held prop.

A skeleton of several roots (read.character_joints) fills its largest hierarchy and keeps
the joints under the other roots as authored. A root control that the animator's rig pins to
a character joint (a leg's IK target on its ankle, a prop in a hand) would then stay on the
unfilled path between keys while the filled joint moves away, and a live IK constraint drags
the filled leg back onto it. Such a control is found from the shot's keys alone: its
position in some character joint's frame is the same at every key (within
:data:`TOLERANCE_M`). Between keys it is moved with the filled joint, keeping its relative
transform interpolated between the keys around (translation lerped, rotation slerped: an IK
target's rotation is often free); its scale and its keys stay as authored.

Matrices here are column-convention numpy (USD's are row-vector); quaternions xyzw.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.usd.keys import key_distance
from pipeline.usd.read import TIME_EPS, character_joints, rest_values

#: A control follows a joint when its position in the joint's frame stays within this of
#: its mean over the keys (metres, converted to skeleton units). An IK solver that reaches
#: its target leaves the effector on it to well under a millimetre and a held prop is rigid,
#: but a target keyed a little beyond the limb's reach (a walk's stretched contact leg) leaves
#: the limb short of it by that much: 1.9 cm at some keys of the Blender export in
#: tests/fixtures/blender, 1.1 cm from its mean offset. A control keyed on its own drifts
#: more against every joint (that export's knee pole: 2.4 cm against its nearest, the chest).
TOLERANCE_M = 0.02


@dataclass
class Rig:
    """What forward kinematics needs of a skeleton of several roots, in its joint order."""

    joints: tuple[str, ...]
    parents: np.ndarray  # (S,) parent index, -1 for a root
    rest: np.ndarray  # (S, 4, 4) local rest transforms (column convention)
    character: np.ndarray  # (S,) bool: under the character's root
    skel_of: np.ndarray  # (A,) skeleton index of each joint the animation lists, -1 for none
    tolerance: float  # TOLERANCE_M in skeleton units
    unauthored: (
        dict  # per attribute, (A, 4|3): what shows where the animation authors none (read.rest_values)
    )


@dataclass
class Follow:
    """A kept root control (``slot`` in the animation's joints) and the character joint it
    follows (skeleton index ``joint``; -1: none), with its largest deviation over the keys
    (skeleton units) and its transform relative to the joint at each key."""

    slot: int
    joint: int
    deviation: float
    keys: np.ndarray  # (K,)
    rel_t: np.ndarray | None = None  # (K, 3) translation in the joint's frame
    rel_q: np.ndarray | None = None  # (K, 4) rotation relative to the joint's


def rig_of(stage, skel_path: str, authored: list[str]) -> Rig | None:
    """The rig of the skeleton at ``skel_path`` (UsdSkel's topology and rest transforms) with
    the animation's joints ``authored`` mapped on it; None for a skeleton of one root."""
    from pxr import Usd, UsdGeom, UsdSkel

    prim = stage.GetPrimAtPath(skel_path)
    query = UsdSkel.Cache().GetSkelQuery(UsdSkel.Skeleton(prim)) if prim else None
    if not query:
        return None
    joints = tuple(str(t) for t in query.GetJointOrder())
    parents = np.array(query.GetTopology().GetParentIndices(), np.int64)
    main, _ = character_joints(list(joints), parents)
    rest = query.ComputeJointLocalTransforms(Usd.TimeCode.Default(), True)
    if main is None or not rest:
        return None
    character = np.zeros(len(joints), bool)
    character[main] = True
    at = {t: i for i, t in enumerate(joints)}
    world = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(stage.GetStartTimeCode()))
    scale = abs(np.linalg.det(world[:3, :3])) ** (1 / 3) or 1.0  # skeleton units to the stage's
    return Rig(
        joints=joints,
        parents=parents,
        rest=np.swapaxes(np.array(rest, np.float64), -1, -2),
        character=character,
        skel_of=np.array([at.get(t, -1) for t in authored], np.int64),
        tolerance=TOLERANCE_M / UsdGeom.GetStageMetersPerUnit(stage) / scale,
        unauthored=rest_values(stage, skel_path, authored),
    )


def skel_space(rig: Rig, rot, trans, scale) -> np.ndarray:
    """(T, S, 4, 4) skeleton-space transforms from the animation's (T, A, 4|3) local values
    (joints it does not list at rest): UsdSkel's local ``T·R·S``, concatenated down the tree
    one depth at a time (every joint of a depth, every time, in one product)."""
    from scipy.spatial.transform import Rotation

    T = len(rot)
    local = np.broadcast_to(rig.rest, (T, *rig.rest.shape)).copy()
    has = rig.skel_of >= 0
    idx = rig.skel_of[has]
    r = Rotation.from_quat(np.asarray(rot, np.float64)[:, has].reshape(-1, 4)).as_matrix()
    r = r.reshape(T, len(idx), 3, 3) * np.asarray(scale, np.float64)[:, has, None, :]
    m = local[:, idx]
    m[..., :3, :3] = r
    m[..., :3, 3] = np.asarray(trans, np.float64)[:, has]
    local[:, idx] = m
    depth = np.zeros(len(rig.parents), np.int64)
    for j, p in enumerate(rig.parents):  # parents come first (UsdSkel's topology order)
        depth[j] = 0 if p < 0 else depth[p] + 1
    out = local
    for d in range(1, int(depth.max(initial=0)) + 1):
        level = np.flatnonzero(depth == d)
        out[:, level] = out[:, rig.parents[level]] @ local[:, level]
    return out


def _unit_rotations(mats: np.ndarray):
    """The rotations of (..., 4, 4) transforms, their scale removed: the orthogonal polar
    factor (by SVD), negated where the joint is mirrored (a scale of -1, as a Maya rig's
    right side may carry), which is a proper rotation that moves continuously with the joint
    (flipping one singular vector instead jumped up to 180° a frame where two scales tie);
    scipy's from_matrix refuses a mirrored or vanishing matrix."""
    from scipy.spatial.transform import Rotation

    u, _, vt = np.linalg.svd(mats[..., :3, :3].reshape(-1, 3, 3))
    q = u @ vt
    return Rotation.from_matrix(q * np.sign(np.linalg.det(q))[:, None, None])


#: Frames whose skeleton-space transforms are computed at once: bounds the memory of a long
#: shot's fill (every joint's 4x4 at 30,000 frames of a 100-joint rig was 1.2 GB).
BLOCK = 4096


def _skel_blocks(rig: Rig, rot, trans, scale, rows=None):
    """(rows, their (B, S, 4, 4) skeleton-space transforms) over the ``rows`` (default all)
    of the animation values ``rot``/``trans``/``scale``, :data:`BLOCK` rows at a time."""
    rows = np.arange(len(rot)) if rows is None else rows
    for s in range(0, len(rows), BLOCK):
        b = rows[s : s + BLOCK]
        yield b, skel_space(rig, rot[b], trans[b], scale[b])


def detect(rig: Rig, keys: np.ndarray, rot, trans, scale) -> list[Follow]:
    """Per kept root control the animation lists, the character joint it follows over
    ``keys`` (its (K, A, ...) values there), or joint -1: fewer than two keys, a control that
    does not move over them (it follows a still joint as well as none), or none within the
    tolerance. The joint of the smallest deviation wins; rotation may vary."""
    from scipy.spatial.transform import Rotation

    keys = np.asarray(keys, np.float64)
    slots = [a for a, s in enumerate(rig.skel_of) if s >= 0 and rig.parents[s] < 0 and not rig.character[s]]
    if not slots:
        return []
    if len(keys) < 2:
        return [Follow(a, -1, np.inf, keys) for a in slots]
    chars = np.flatnonzero(rig.character)
    K, C = len(keys), len(chars)
    # Per key, each character joint's rotation-scale and position, and each control's
    # position: a block of keys' skeleton at a time, the rest never held whole.
    lin, at = np.empty((K, C, 3, 3)), np.empty((K, C, 3))
    ctl = {a: np.empty((K, 3)) for a in slots}
    for b, world in _skel_blocks(rig, rot, trans, scale):
        w = world[:, chars]
        lin[b], at[b] = w[..., :3, :3], w[..., :3, 3]
        for a in slots:  # a root: its local is its skeleton-space transform
            ctl[a][b] = world[:, rig.skel_of[a], :3, 3]
    # A joint scaled to nothing at a key has no frame to be followed in.
    det = np.linalg.det(lin)
    flat = (np.abs(det) < 1e-12).any(0)
    inv = np.linalg.inv(np.where(np.abs(det)[..., None, None] < 1e-12, np.eye(3), lin))  # (K, C, 3, 3)
    out = []
    for a in slots:
        c = ctl[a]
        p = (inv @ (c[:, None] - at)[..., None])[..., 0]  # (K, C, 3): in each joint's frame
        # How far the control is from where the mean relative position would put it.
        off = (lin @ (p - p.mean(0))[..., None])[..., 0]
        dev = np.where(flat, np.inf, np.linalg.norm(off, axis=-1).max(0))  # (C,)
        # Joints rigid to one another deviate alike (a foot under its shin): the nearest of
        # those is the one the control is on (an IK target on the ankle, not the knee).
        near = np.linalg.norm(c[:, None] - at, axis=-1).mean(0)
        best = int(np.argmin(np.where(dev <= dev.min() + 1e-3 * rig.tolerance, near, np.inf)))
        moves = np.linalg.norm(c - c.mean(0), axis=-1).max() > rig.tolerance
        if not moves or dev[best] > rig.tolerance:
            out.append(Follow(a, -1, float(dev[best]), keys))
            continue
        m = np.zeros((K, 4, 4))
        m[:, :3, :3] = lin[:, best]
        rel_r = _unit_rotations(m).inv() * Rotation.from_quat(np.asarray(rot, np.float64)[:, a])
        out.append(Follow(a, int(chars[best]), float(dev[best]), keys, p[:, best], rel_r.as_quat()))
    return out


def keys_around(keys, lo: float, hi: float) -> np.ndarray:
    """The sorted ``keys`` the fill of ``lo``-``hi`` fills between: those in it and the key
    on either side of it (a --range between keys is filled from the keys around it)."""
    keys, eps = np.sort(np.asarray(keys, np.float64)), TIME_EPS
    before, after = keys[keys <= lo + eps], keys[keys >= hi - eps]
    lo = before[-1] if len(before) else lo
    hi = after[0] if len(after) else hi
    return keys[(keys >= lo - eps) & (keys <= hi + eps)]


def fill_keys(keys, times, moved, inside=None) -> np.ndarray:
    """The keys a take's fill filled between (:func:`keys_around`): around its ``inside``
    times (its fill range) where it carries them, else around the ``times`` where the fill
    ``moved`` the character."""
    times = np.asarray(times, np.float64)
    if inside is not None and len(inside):
        return keys_around(keys, float(np.min(inside)), float(np.max(inside)))
    if np.any(moved):
        t = times[np.asarray(moved, bool)]
        return keys_around(keys, float(t.min()), float(t.max()))
    return np.sort(np.asarray(keys, np.float64))[:0]


def off_keys(keys, times) -> np.ndarray:
    """Whether each of ``times`` is off every one of the ``keys`` (by TIME_EPS)."""
    return key_distance(times, keys) >= TIME_EPS


def apply(rig: Rig, follows: list[Follow], times, rot, trans, scale, moved) -> None:
    """Moves each following control with its joint at the ``times`` where ``moved`` (the
    character differs from the authored animation: inside the fill, off its keys), in place
    in the (T, A, ...) values ``rot`` (f32) and ``trans`` (f32): the joint's filled
    skeleton-space transform times the relative transform interpolated between the keys
    around (held before the first and after the last). Scale stays as authored."""
    live = [f for f in follows if f.joint >= 0]
    times = np.asarray(times, np.float64)
    at = np.flatnonzero(moved)
    if not live or not len(at):
        return
    for block, world in _skel_blocks(rig, rot, trans, scale, at):
        _apply_block(live, times, block, rot, trans, world)


def _apply_block(live, times, at, rot, trans, world) -> None:
    """:func:`apply` at the frames ``at``, whose skeleton-space transforms are ``world``."""
    from scipy.spatial.transform import Rotation

    for f in live:
        t = times[at]
        b = np.clip(np.searchsorted(f.keys, t), 1, len(f.keys) - 1)
        w = np.clip((t - f.keys[b - 1]) / (f.keys[b] - f.keys[b - 1]), 0.0, 1.0)
        rel_t = f.rel_t[b - 1] + (f.rel_t[b] - f.rel_t[b - 1]) * w[:, None]
        ra, rb = Rotation.from_quat(f.rel_q[b - 1]), Rotation.from_quat(f.rel_q[b])
        rel_r = ra * Rotation.from_rotvec((ra.inv() * rb).as_rotvec() * w[:, None])
        m = world[:, f.joint]
        pos = (m[:, :3, :3] @ rel_t[..., None])[..., 0] + m[:, :3, 3]
        q = (_unit_rotations(m) * rel_r).as_quat()
        q *= np.where((q * rot[at, f.slot]).sum(-1) < 0, -1.0, 1.0)[:, None]  # the authored hemisphere
        rot[at, f.slot] = q.astype(np.float32)
        trans[at, f.slot] = pos.astype(np.float32)


def describe(rig: Rig, follows: list[Follow], authored: list[str]) -> str:
    """What the fill does with the kept root controls, for the several-roots warning:
    "between the keys 'foot_ik_L' follows the filled 'Foot_L'; 'knee_pole_L' stays as authored"."""
    name = [t.rsplit("/", 1)[-1] for t in rig.joints]
    by = [f"{authored[f.slot]!r} follows the filled {name[f.joint]!r}" for f in follows if f.joint >= 0]
    still = [repr(authored[f.slot]) for f in follows if f.joint < 0]
    parts = [f"between the keys {', '.join(by)}"] if by else []
    if still:
        parts.append(f"{', '.join(still)} {'stays' if len(still) == 1 else 'stay'} as authored")
    return "; ".join(parts)


def values_at(src, authored: list[str], rig: Rig, times) -> list[np.ndarray]:
    """The animation ``src``'s (T, A, 4|3) rotations, translations and scales at ``times``
    as USD gives them (interpolated between samples); an attribute it never authors, or one
    of another length, as the writer keeps it (``rig.unauthored``: the rest pose, a joint the
    skeleton lacks at identity)."""
    out = []
    for name in ("rotations", "translations", "scales"):
        attr, fallback = src.GetAttribute(name), rig.unauthored[name]
        rows = []
        for t in times:
            v = attr.Get(float(t)) if attr else None
            rows.append(np.array(v, np.float64) if v is not None and len(v) == len(authored) else fallback)
        out.append(np.array(rows, np.float64).reshape(len(rows), len(authored), -1))
    return out


def note(stage, skel_path: str, anim_path: str, keys) -> str | None:
    """:func:`describe` for the skeleton ``skel_path`` animated by ``anim_path`` over
    ``keys``, or None where it keeps no root control (one root, no animated control)."""
    src = stage.GetPrimAtPath(anim_path)
    authored = [str(t) for t in (src.GetAttribute("joints").Get() or [])] if src else []
    rig = rig_of(stage, skel_path, authored) if authored else None
    if rig is None:
        return None
    keys = np.asarray(keys, np.float64)
    values = values_at(src, authored, rig, keys) if len(keys) > 1 else (None, None, None)
    follows = detect(rig, keys, *values)
    return describe(rig, follows, authored) or None


#: How the reader's several-roots warning ends (read._one_hierarchy), replaced where a kept
#: control follows a joint.
_KEPT = (" and keep the animation's values as authored", " and keeps the animation's values as authored")


def roots_line(stage, c, keys) -> str:
    """The several-roots warning of the character ``c`` (read.Character) for a fill: with
    which of its kept root controls follow which filled joint over ``keys`` (the keys the
    fill fills between: :func:`keys_around` its range) and which stay as authored; the
    reader's line where none follows."""
    said = note(stage, c.skel_path, c.anim_path, keys)
    line = c.extra["roots"]
    if not said or " follows " not in said:
        return line
    for end in _KEPT:
        line = line.removesuffix(end)
    return f"{line}: {said}"
