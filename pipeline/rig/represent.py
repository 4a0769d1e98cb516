"""GANimator's motion representation: per frame, one 6-channel block per vertex.

Layout of the F0 = 6·V feature channels (V = J + C + 1, see :mod:`pipeline.rig.topology`):

- joint j: its local rotation in 6D (the first two matrix columns, as
  :func:`pipeline.motion.rotations.matrix_to_6d`); the root joint's is its global rotation;
- contact vertex c: the contact label (0/1) in its first channel, zeros elsewhere;
- root-displacement vertex: root x and z velocity (per frame) and root height y, divided by
  the rig's size ``scale``, then three zeros.

Everything is computed in a Y-up frame: a Z-up skeleton's root is turned by −90° about X on
the way in and back on the way out, so heights, horizontal velocities, contact labels and
the foot-locking IK all use Y as up whatever the source's axis. Positions are in the
source's units; the root channels are in rig sizes (``scale``, the first frame's extent
along up), so one model trains the same on a rig in centimetres or in metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.motion.clip import Motion
from pipeline.motion.fk import fk
from pipeline.motion.rotations import matrix_to_6d, matrix_to_quat, quat_mul, quat_to_matrix, sixd_to_matrix
from pipeline.motion.skeleton import Skeleton

# Z-up → Y-up: −90° about X maps +Z to +Y (xyzw).
_ZUP_TO_YUP = np.array([-np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)])
CONTACT_SPEED = 0.3  # rig sizes per second: slower than this counts as planted
CONTACT_HEIGHT = 0.08  # rig sizes above the clip's lowest contact joint
GROUND_FRACTION = 0.1  # a contact joint is near the floor in at least this share of frames


@dataclass
class RigSpec:
    """What the representation needs to know about a rig (stored in rig.json)."""

    skeleton: Skeleton
    contacts: list[int]  # joint indices of the contact joints
    scale: float  # rig size in source units (root channels and thresholds are relative to it)
    fps: float
    floor: float = 0.0  # lowest contact-joint height in the training clip (Y-up, source units)
    extra: dict = field(default_factory=dict)

    @property
    def n_vertices(self) -> int:
        return len(self.skeleton) + len(self.contacts) + 1

    @property
    def channels(self) -> int:
        return 6 * self.n_vertices

    @property
    def legs(self) -> list[tuple[int, int, int, int]]:
        """(grandparent, parent, joint, joint) per contact joint, for ``post.lock_feet``."""
        p = self.skeleton.parents
        return [(int(p[p[j]]), int(p[j]), int(j), int(j)) for j in self.contacts]


def _rot_root(q_root: np.ndarray, pos: np.ndarray, up: str, inverse: bool = False):
    if up == "Y":
        return q_root, pos
    from pipeline.motion.rotations import quat_apply, quat_inv

    fix = quat_inv(_ZUP_TO_YUP) if inverse else _ZUP_TO_YUP
    return quat_mul(np.broadcast_to(fix, q_root.shape), q_root.astype(np.float64)), quat_apply(fix, pos)


def to_yup(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """Local rotations and root positions with the root turned into a Y-up frame."""
    rot = motion.rotations.astype(np.float64).copy()
    q0, pos = _rot_root(rot[:, 0], motion.root_positions.astype(np.float64), motion.skeleton.up_axis)
    rot[:, 0] = q0
    return rot, np.asarray(pos, np.float64)


def from_yup(rot: np.ndarray, root: np.ndarray, skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    rot = np.array(rot, np.float64)
    q0, pos = _rot_root(rot[:, 0], np.asarray(root, np.float64), skeleton.up_axis, inverse=True)
    rot[:, 0] = q0
    return rot, np.asarray(pos, np.float64)


def yup_positions(motion: Motion) -> np.ndarray:
    rot, root = to_yup(motion)
    return fk(rot, root, motion.skeleton.parents, motion.skeleton.offsets)[1]


def rig_scale(motion: Motion) -> float:
    """The rig's size: the first frame's extent along up (bone lengths as a fallback)."""
    y = yup_positions(motion.slice(0, 1))[0, :, 1]
    ext = float(y.max() - y.min())
    bones = float(motion.skeleton.bone_lengths()[1:].sum())
    return ext if ext > 0.05 * bones else max(bones, 1e-6)


def default_contacts(motion: Motion, scale: float) -> list[int]:
    """Joints that touch the floor: below ``CONTACT_HEIGHT`` rig sizes above the lowest joint
    in at least ``GROUND_FRACTION`` of the frames, and deep enough for a two-bone IK chain."""
    pos = yup_positions(motion)
    y = pos[..., 1]
    floor = y.min()
    parents = motion.skeleton.parents
    out = []
    for j in range(len(parents)):
        if parents[j] < 0 or parents[parents[j]] < 0:
            continue
        if np.mean(y[:, j] - floor < CONTACT_HEIGHT * scale) >= GROUND_FRACTION:
            out.append(j)
    if len(out) > 8:  # keep the eight lowest on average
        out = sorted(sorted(out, key=lambda j: y[:, j].mean())[:8])
    return out


def contact_labels(motion: Motion, spec: RigSpec) -> np.ndarray:
    """(T, C) 0/1: contact joint slower than ``CONTACT_SPEED`` and near the floor."""
    if not spec.contacts:
        return np.zeros((len(motion), 0), np.float32)
    pos = yup_positions(motion)[:, spec.contacts]
    speed = np.zeros(pos.shape[:2])
    speed[1:] = np.linalg.norm(np.diff(pos, axis=0), axis=-1) * motion.fps
    speed[0] = speed[1] if len(speed) > 1 else 0.0
    low = pos[..., 1] - spec.floor < CONTACT_HEIGHT * spec.scale
    return ((speed < CONTACT_SPEED * spec.scale) & low).astype(np.float32)


def make_spec(motion: Motion, contacts: list[int] | None = None) -> RigSpec:
    scale = rig_scale(motion)
    if contacts is None:
        contacts = default_contacts(motion, scale)
    floor = float(yup_positions(motion)[:, contacts, 1].min()) if contacts else 0.0
    return RigSpec(motion.skeleton, list(contacts), scale, float(motion.fps), floor)


def encode(motion: Motion, spec: RigSpec) -> tuple[np.ndarray, np.ndarray]:
    """Features (F0, T) float32 and the first frame's root position (3,) in the Y-up frame."""
    rot, root = to_yup(motion)
    T, J = rot.shape[:2]
    C = len(spec.contacts)
    feat = np.zeros((T, spec.n_vertices, 6), np.float64)
    feat[:, :J] = matrix_to_6d(quat_to_matrix(rot))
    feat[:, J : J + C, 0] = contact_labels(motion, spec)
    vel = np.zeros((T, 3))
    vel[1:] = np.diff(root, axis=0)
    feat[:, -1, 0] = vel[:, 0] / spec.scale
    feat[:, -1, 1] = root[:, 1] / spec.scale
    feat[:, -1, 2] = vel[:, 2] / spec.scale
    return feat.reshape(T, -1).T.astype(np.float32), root[0].astype(np.float32)


def decode(
    feat: np.ndarray, spec: RigSpec, begin: np.ndarray, fps: float | None = None, name: str = ""
) -> tuple[Motion, np.ndarray]:
    """The motion (source frame and up axis) and contact probabilities (T, C) of features (F0, T)."""
    T = feat.shape[-1]
    J, C = len(spec.skeleton), len(spec.contacts)
    f = np.asarray(feat, np.float64).T.reshape(T, spec.n_vertices, 6)
    rot = matrix_to_quat(sixd_to_matrix(f[:, :J]))
    root = np.empty((T, 3))
    root[:, 1] = f[:, -1, 1] * spec.scale
    for a in (0, 2):
        steps = f[:, -1, a] * spec.scale
        steps[0] = 0.0
        root[:, a] = begin[a] + np.cumsum(steps)
    rot, root = from_yup(rot, root, spec.skeleton)
    contacts = np.clip(f[:, J : J + C, 0], 0.0, 1.0).astype(np.float32)
    return Motion(
        spec.skeleton, rot.astype(np.float32), root.astype(np.float32), fps or spec.fps, name
    ), contacts


def resample_linear(x: np.ndarray, n: int) -> np.ndarray:
    """(C, T) → (C, n), linear with half-pixel centres (torch ``interpolate``'s
    ``align_corners=False``), so numpy inference and torch training agree."""
    T = x.shape[-1]
    if n == T:
        return x.copy()
    src = (np.arange(n) + 0.5) * (T / n) - 0.5
    src = np.maximum(src, 0.0)
    i0 = np.minimum(np.floor(src).astype(np.int64), T - 1)
    i1 = np.minimum(i0 + 1, T - 1)
    w = (src - i0).astype(x.dtype)
    return x[..., i0] * (1 - w) + x[..., i1] * w


def pyramid_lengths(T: int, ratio: float, factor: float = 4.0 / 3.0, min_len: int = 4) -> list[int]:
    """Coarse-to-fine lengths: int(T·ratio), then ×4/3 (at least +1) until ≥ T; the last is T."""
    lens = [max(int(T * ratio), min_len)]
    while lens[-1] < T:
        nxt = int(lens[-1] * factor)
        lens.append(nxt if nxt > lens[-1] else lens[-1] + 1)
    lens[-1] = T
    return lens
