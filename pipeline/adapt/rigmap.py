"""A character on its own per-rig model: no retargeting, only joint order, up axis and units.

A rig model is trained on the rig's own skeleton-space animation (local joint rotations,
the root joint's local translation; :mod:`pipeline.rig.source`), in the up axis and unit
its ``rig.json`` names: the stage's up axis as seen from skeleton space (through the
Skeleton's world transform) and ``metersPerUnit`` times the skeleton's world scale. A
shot's character with the same skeleton is handed to it as is: rotations reordered into
the model's joint order, and the root's rotation and translation turned from the
character's skeleton-space up axis and unit into the model's. Same up axis and unit (the
usual case: the shot the model was trained from, or a shot of the same asset): the values
pass through untouched, bit for bit.
"""

from __future__ import annotations

import numpy as np

from pipeline.adapt.rig import Rig
from pipeline.motion.rotations import matrix_to_quat, quat_inv, quat_mul

_Z_TO_Y = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # (x, y, z) Z-up → (x, z, -y) Y-up


def skeleton_space(char: Rig, stage_up: str, stage_mpu: float) -> tuple[str, float]:
    """(up axis "Y"/"Z" or "" when it is X or down, metres per unit) of ``char``'s skeleton
    space: the stage's up axis through the skeleton's world rotation, and the stage unit
    times the skeleton's world scale (the same rule as the rig model's source clip)."""
    m = char.skel_to_world[:3, :3]
    scale = float(np.cbrt(abs(np.linalg.det(m))))
    up = np.array([0.0, 1.0, 0.0]) if stage_up == "Y" else np.array([0.0, 0.0, 1.0])
    r = m / np.linalg.norm(m, axis=0, keepdims=True)
    local = r.T @ up
    axis = int(np.argmax(np.abs(local)))
    name = "" if axis == 0 or local[axis] < 0 else "YZ"[axis - 1]
    return name, float(stage_mpu) * scale


def up_fix(src: str, dst: str) -> np.ndarray:
    """Rotation taking ``src``-up coordinates to ``dst``-up coordinates (Y or Z)."""
    if src == dst:
        return np.eye(3)
    return _Z_TO_Y if (src, dst) == ("Z", "Y") else _Z_TO_Y.T


class RigMap:
    """Same interface as :class:`pipeline.adapt.retarget.Retarget`: skeleton-ordered locals of
    the character ↔ the rig model's joint order and space."""

    def __init__(self, char: Rig, info, perm: np.ndarray, up_axis: str, meters_per_unit: float):
        """``up_axis``/``meters_per_unit``: the character's skeleton space (:func:`skeleton_space`)."""
        self.char, self.info = char, info
        self.perm = np.asarray(perm, np.int64)  # perm[m] = skeleton index of model joint m
        self.R = up_fix(up_axis, info.up_axis)
        self.s = float(meters_per_unit) / info.meters_per_unit
        self.q_R = matrix_to_quat(self.R)
        self.identity = np.array_equal(self.R, np.eye(3)) and self.s == 1.0
        self.root = int(self.perm[0])

    def to_model(self, rot: np.ndarray, trans: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(T,J,4)/(T,J,3) skeleton order → model-ordered local rotations (T,J,4), root (T,3)."""
        local = rot[:, self.perm].astype(np.float32)
        root = trans[:, self.root].astype(np.float32)
        if self.identity:
            return local, root.copy()
        T = rot.shape[0]
        local[:, 0] = quat_mul(np.broadcast_to(self.q_R, (T, 4)), local[:, 0].astype(np.float64))
        root = (self.s * root.astype(np.float64) @ self.R.T).astype(np.float32)
        return local, root

    def from_model(
        self, local: np.ndarray, root: np.ndarray, rot_orig: np.ndarray, trans_orig: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Model local (T,J,4)/root (T,3) → skeleton-ordered rotations and translations;
        every translation but the root's keeps ``trans_orig`` (bone lengths are the rig's)."""
        rot = rot_orig.astype(np.float32).copy()
        trans = trans_orig.astype(np.float32).copy()
        rot[:, self.perm] = local
        if self.identity:
            trans[:, self.root] = root
            return rot, trans
        T = local.shape[0]
        rot[:, self.root] = quat_mul(
            np.broadcast_to(quat_inv(self.q_R), (T, 4)), local[:, 0].astype(np.float64)
        )
        trans[:, self.root] = (root.astype(np.float64) @ self.R) / self.s
        return rot, trans


class OwnRig:
    """A character interpolated on its own rig (``--model interp``): no mapping, no model
    skeleton. Rotations pass through as they are; the root joint's translation is the
    root path; every other translation keeps the shot's own (USD-interpolated) values."""

    reference = "own rig"

    def __init__(self, char: Rig):
        from pipeline.motion.skeleton import Skeleton

        self.char = char
        roots = np.flatnonzero(char.parents < 0)
        self.root = int(roots[0])
        self.missing: list[str] = []
        self.skeleton = Skeleton(
            tuple(char.names), char.parents, char.rest_trans.astype(np.float32), "Y", 0.01
        )

    def to_model(self, rot: np.ndarray, trans: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return rot.astype(np.float32).copy(), trans[:, self.root].astype(np.float32).copy()

    def from_model(
        self, local: np.ndarray, root: np.ndarray, rot_orig: np.ndarray, trans_orig: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        trans = trans_orig.astype(np.float32).copy()
        trans[:, self.root] = root
        return local.astype(np.float32), trans
