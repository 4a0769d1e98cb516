"""What a library frame is matched on, and its foot contacts.

A pose is its joints' positions relative to the root, turned to face +X (the pose bank's
features, :func:`pipeline.data.posebank.pose_features`: where the character stands and which
way it faces do not matter), in cm on the model skeleton, plus the root's height: a crouch
and a stand with the same limbs are different keys. The squared distance between two frames'
features, divided by the joints, is the mean squared joint-position miss in cm².
"""

from __future__ import annotations

import numpy as np

from pipeline.data.posebank import posed_features
from pipeline.data.skeletons import FOOT_JOINTS, bandai_skeleton
from pipeline.motion.fk import fk

#: Feature columns: the joints' root-relative positions (J × 3), then the root height.
HEIGHT = -1
#: An ankle moving less than this (cm a frame at 30 fps: 24 cm/s) touches the ground.
CONTACT_CM = 0.8
#: Frames featurised at once (FK's float64 temporaries follow the block).
BLOCK = 16384


def frame_features(rots: np.ndarray, roots: np.ndarray, skeleton=None) -> tuple[np.ndarray, np.ndarray]:
    """(F, J*3 + 1) float32 features of (F, J, 4) local rotations and (F, 3) roots, and (F, 4)
    the yaw quaternions turning each pose to face +X: one forward kinematics for both."""
    skel = skeleton or bandai_skeleton()
    feats = np.empty((len(rots), len(skel) * 3 + 1), np.float32)
    turn = np.empty((len(rots), 4))
    for s in range(0, len(rots), BLOCK):
        b = slice(s, s + BLOCK)
        _, pos = fk(
            np.asarray(rots[b], np.float64), np.asarray(roots[b], np.float64), skel.parents, skel.offsets
        )
        f, turn[b] = posed_features(pos, skel)
        feats[b, :-1] = f.reshape(len(f), -1)
        feats[b, HEIGHT] = roots[b, 1]
    return feats, turn


def contacts(rots: np.ndarray, roots: np.ndarray, skeleton=None) -> np.ndarray:
    """(F, 2) uint8: each foot (left, right) on the ground at each frame of one take, from
    its ankle's speed (the slower of the steps into and out of the frame)."""
    skel = skeleton or bandai_skeleton()
    ankles = [skel.index(FOOT_JOINTS[0]), skel.index(FOOT_JOINTS[2])]
    if len(rots) < 2:
        return np.ones((len(rots), 2), np.uint8)
    _, p = fk(np.asarray(rots, np.float64), np.asarray(roots, np.float64), skel.parents, skel.offsets,
              joints=ankles)  # fmt: skip
    step = np.linalg.norm(np.diff(p[:, ankles], axis=0), axis=-1)  # (F - 1, 2)
    speed = np.minimum(np.r_[step[:1], step], np.r_[step, step[-1:]])
    return (speed < CONTACT_CM).astype(np.uint8)
