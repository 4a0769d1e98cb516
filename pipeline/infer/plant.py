"""Feet the keys plant stay planted: the trusted fill's curve with a foot held between two keys.

A spline through the keys moves the root and each leg's rotations on curves of their own, so a
foot the animator planted at two keys drifts between them: the sum of those curves does not
hold it still. Where both keys of a gap hold a foot near the ground and in nearly the same
place, the foot is taken as planted through the gap: its ankle is held on the line between the
two keys' ankle positions and its orientation slerped between theirs, by the fill's own
two-bone IK (:func:`pipeline.infer.post.lock_feet`, anchored at the keys), so keys stay exact
and bone lengths do not change. Nothing is learned: it holds on any rig whose legs map, for
any actor.

The constants were chosen on tuning takes (``experiments/foot_plant.py``: CMU subjects 1-3 on
the model skeleton, and every third Bandai dataset-2 train take numbered 3 mod 5), the curve's
error between the keys ÷ the curve's without it, keys every 10 / 30 frames: CMU 0.962 / 0.986,
Bandai 0.981 / 0.998, no take worse than 1.014; heights 6-15 cm and travels 3-10 cm were within
0.005 of that. Holding only the ankle's place on the ground, not its height: CMU 0.971 / 0.990,
Bandai 0.988 / 0.998.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipeline.motion.clip import Motion
from pipeline.motion.fk import fk
from pipeline.motion.rotations import batch_quat_mul, matrix_to_quat

#: A foot is on the ground at a key when its ankle is at most this high (cm) above the lowest
#: that ankle is at any key of the shot.
PLANT_HEIGHT_CM = 10.0
#: ... and planted through a gap when its ankle moves at most this far (cm, along the ground)
#: from the gap's first key to its last.
PLANT_TRAVEL_CM = 6.0

#: A thigh or shin shorter than this (cm) is no leg to hold a foot with (a rig's stand-in joint).
MIN_BONE_CM = 1.0

#: Frames the IK holds feet in at once (from key to key): memory follows it, not the shot.
PLANT_BLOCK = 4096

_Y_UP_FROM_Z_UP = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])


@dataclass(frozen=True)
class Feet:
    """The legs of a skeleton, as the IK takes them, and its space.

    ``legs``: (hip, knee, ankle, toe) skeleton indices per leg, left then right, each of hip,
    knee and ankle an ancestor of the next; ``to_y_up``: the rotation (3x3) from the skeleton's
    space to one whose Y is up; ``cm_per_unit``: centimetres per unit of that space.
    """

    legs: tuple[tuple[int, int, int, int], ...]
    to_y_up: np.ndarray
    cm_per_unit: float


def feet_of(
    skeleton, legs, to_y_up: np.ndarray | None = None, cm_per_unit: float | None = None
) -> Feet | None:
    """:class:`Feet` of ``skeleton`` for ``legs`` ((hip, knee, ankle, toe) indices, or None
    where a joint is missing), or None when a leg lacks a hip, knee or ankle, has them out of
    order (each the ancestor of the next; joints between them are kept as they are), a hip
    that is the root (it would be turned with the body, :func:`plant_feet`) or a thigh or shin
    under :data:`MIN_BONE_CM` (their rest offsets). Space: the skeleton's own up axis and
    unit unless given."""
    # The toe is not moved (the IK sets hip, knee and ankle): a rig without one uses the ankle.
    legs = tuple((*leg[:3], leg[2] if leg[3] is None else leg[3]) for leg in legs)
    parents = np.asarray(skeleton.parents)
    offsets = np.asarray(skeleton.offsets, np.float64)
    if to_y_up is None:
        to_y_up = np.eye(3) if skeleton.up_axis == "Y" else _Y_UP_FROM_Z_UP
    if cm_per_unit is None:
        cm_per_unit = 100.0 * float(skeleton.meters_per_unit)
    for leg in legs:
        if any(j is None or j < 0 for j in leg) or parents[leg[0]] < 0:
            return None
        for top, end in ((leg[0], leg[1]), (leg[1], leg[2])):  # thigh, shin
            length = _chain_length(parents, offsets, top, end) * cm_per_unit
            if not (np.isfinite(length) and length >= MIN_BONE_CM):  # not below it, or no bone
                return None
    return Feet(legs, np.asarray(to_y_up, np.float64), float(cm_per_unit))


def _chain_length(parents: np.ndarray, offsets: np.ndarray, top: int, end: int) -> float:
    """The rest offsets' length (skeleton units) from ``end`` up to its ancestor ``top``, or
    NaN when ``top`` is not above ``end``."""
    length, j = 0.0, end
    while j != top:
        if j < 0:
            return float("nan")
        length += float(np.linalg.norm(offsets[j]))
        j = int(parents[j])
    return length


def legs_named(index) -> list[tuple]:
    """(hip, knee, ankle, toe) per leg, left then right, of the model's leg joints as
    ``index`` (model joint name -> skeleton index) finds them; None where it has no joint."""
    from pipeline.data.skeletons import LEGS

    return [tuple(index.get(n) for n in leg) for leg in LEGS]


def model_feet(skeleton) -> Feet | None:
    """:class:`Feet` of a skeleton that carries the model's leg joint names, else None."""
    return feet_of(skeleton, legs_named({n: i for i, n in enumerate(skeleton.names)}))


def planted(ankles_cm: np.ndarray, breaks=()) -> np.ndarray:
    """(K - 1, L) bool: leg l planted through the gap from key k to key k + 1, from its ankle
    positions at the keys (K, L, 3; Y up, cm). ``breaks``: (k, k + 1) key indices with a cut
    between, never planted."""
    height = ankles_cm[..., 1] - ankles_cm[..., 1].min(axis=0)
    low = height <= PLANT_HEIGHT_CM
    travel = np.linalg.norm((ankles_cm[1:] - ankles_cm[:-1])[..., [0, 2]], axis=-1)
    out = low[:-1] & low[1:] & (travel <= PLANT_TRAVEL_CM)
    for a, _ in breaks:
        out[a] = False
    return out


def plant_feet(motion: Motion, keys: np.ndarray, feet: Feet, breaks=()) -> Motion:
    """:func:`plant_rotations` on a motion: same skeleton, root path, rate and length."""
    rot = plant_rotations(motion.rotations, motion.root_positions, motion.skeleton, keys, feet, breaks)
    return motion if rot is motion.rotations else replace(motion, rotations=rot)


def plant_rotations(rot: np.ndarray, root: np.ndarray, skeleton, keys, feet: Feet, breaks=()) -> np.ndarray:
    """Local rotations ``rot`` (T, J, 4) of a fill through ``keys`` (sorted unique frames;
    root path ``root`` (T, 3)) with each foot the keys plant held through the gap
    (:func:`planted`); ``breaks``: (a, b) key frames with a cut between. Only the legs' hip,
    knee and ankle rotations change; key frames stay bitwise; ``rot`` itself where no foot
    is planted."""
    from pipeline.infer.post import lock_feet

    keys = np.asarray(keys, np.int64)
    if len(keys) < 2:
        return rot
    legs = list(feet.legs)
    ankles = [leg[2] for leg in legs]
    _, pos = fk(rot[keys].astype(np.float64), root[keys].astype(np.float64), skeleton.parents,
                skeleton.offsets, joints=ankles)  # fmt: skip
    ankles_cm = pos[:, ankles] @ feet.to_y_up.T * feet.cm_per_unit
    index = {int(k): i for i, k in enumerate(keys)}
    pairs = [(index[a], index[b]) for a, b in breaks if a in index and b in index]
    gaps = planted(ankles_cm, pairs)
    if not gaps.any():
        return rot
    contacts = np.zeros((len(rot), len(legs)), np.float32)
    for g, li in zip(*np.nonzero(gaps), strict=True):
        contacts[keys[g] : keys[g + 1] + 1, li] = 1.0
    # The IK holds the ground plane as X-Z: turn the whole body into the Y-up space (the root
    # joint's rotation and position; every local below it is unchanged) and take back the legs.
    root_joint = int(np.flatnonzero(np.asarray(skeleton.parents) < 0)[0])
    q = matrix_to_quat(feet.to_y_up)
    moved = [j for leg in legs for j in leg[:3]]
    out = rot.copy()
    # Only the runs of gaps a foot is held in, in blocks from key to key: a held gap's frames
    # depend on its own keys alone, so the blocks give what the whole shot would, and memory
    # follows PLANT_BLOCK, not the shot.
    for first, last in _blocks(keys, gaps.any(axis=1), PLANT_BLOCK):
        a, b = int(keys[first]), int(keys[last]) + 1
        turned = rot[a:b].astype(np.float64)  # a copy: the caller's array is not touched
        turned[:, root_joint] = batch_quat_mul(np.broadcast_to(q, (b - a, 4)), turned[:, root_joint])
        locked = lock_feet(turned, root[a:b].astype(np.float64) @ feet.to_y_up.T, skeleton, contacts[a:b],
                           keys[first : last + 1] - a, legs, anchor=True, orient=True, height=True)  # fmt: skip
        if not np.isfinite(locked[:, moved]).all():  # no pose reaches the line: the curve as it is
            return rot
        out[a:b, moved] = locked[:, moved].astype(rot.dtype)
    out[keys] = rot[keys]
    return out


def _blocks(keys: np.ndarray, held: np.ndarray, block: int) -> list[tuple[int, int]]:
    """(first, last) key indices of the runs of gaps ``held`` (K - 1,) marks, each cut at keys
    into spans of at most ``block`` frames (a single longer gap is a span of its own)."""
    out, g = [], 0
    while g < len(held):
        if not held[g]:
            g += 1
            continue
        first = g
        while g + 1 < len(held) and held[g + 1] and keys[g + 2] - keys[first] <= block:
            g += 1
        out.append((first, g + 1))
        g += 1
    return out
