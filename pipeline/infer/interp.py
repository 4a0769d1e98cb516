"""The interpolation baseline: LERP of the root, SLERP of local rotations, between keys."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from pipeline.data.skeletons import bandai_skeleton
from pipeline.infer.api import Capabilities, refuse_extras
from pipeline.motion.clip import Motion
from pipeline.motion.rotations import slerp


def interpolate_between(rot0, rot1, pos0, pos1, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The n frames strictly between two poses: weights ``linspace(0, 1, n + 2)[1:-1]``."""
    w = np.linspace(0.0, 1.0, n + 2)[1:-1]
    rot = slerp(rot0, rot1, w)
    wp = w.reshape((-1,) + (1,) * np.ndim(pos0))
    pos = (1.0 - wp) * np.asarray(pos0, np.float64) + wp * np.asarray(pos1, np.float64)
    return rot, pos


def interpolate_keys(motion: Motion, keys: np.ndarray) -> Motion:
    """Every frame between consecutive keys interpolated; outside the keys, held."""
    keys = np.unique(np.asarray(keys, np.int64))
    if len(keys) < 2:
        raise ValueError("interpolation needs at least two keys")
    rot = motion.rotations.copy()
    pos = motion.root_positions.copy()
    for a, b in zip(keys[:-1], keys[1:], strict=True):
        if b - a > 1:
            r, p = interpolate_between(rot[a], rot[b], pos[a], pos[b], int(b - a - 1))
            rot[a + 1 : b] = r
            pos[a + 1 : b] = p
    rot[: keys[0]] = rot[keys[0]]
    pos[: keys[0]] = pos[keys[0]]
    rot[keys[-1] + 1 :] = rot[keys[-1]]
    pos[keys[-1] + 1 :] = pos[keys[-1]]
    return replace(motion, rotations=rot, root_positions=pos)


class InterpolationInbetweener:
    """SLERP/LERP between keys; on any skeleton, at any frame rate."""

    name = "interpolation"
    model_hash = "none"
    fps = 30.0
    capabilities = Capabilities(any_rig=True)

    def __init__(self):
        self.skeleton = bandai_skeleton()

    def fill(self, motion: Motion, keys: np.ndarray, seed: int = 0, joint_keys=None, dna=None) -> Motion:
        refuse_extras(self, joint_keys, dna)
        return interpolate_keys(motion, keys)
