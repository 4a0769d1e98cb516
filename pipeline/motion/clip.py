"""A motion clip: local joint rotations and a root trajectory on a skeleton."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipeline.motion import fk as _fk
from pipeline.motion.rotations import quat_continuity, quat_normalize, slerp_pairs
from pipeline.motion.skeleton import Skeleton


@dataclass(eq=False)
class Motion:
    """``rotations`` (T, J, 4) unit quaternions xyzw float32, ``root_positions`` (T, 3)."""

    skeleton: Skeleton
    rotations: np.ndarray
    root_positions: np.ndarray
    fps: float
    name: str = ""

    def __post_init__(self):
        self.rotations = np.asarray(self.rotations, np.float32)
        self.root_positions = np.asarray(self.root_positions, np.float32)
        T, J = self.rotations.shape[:2]
        if self.rotations.shape != (T, len(self.skeleton), 4):
            raise ValueError(f"motion {self.name!r}: rotations {self.rotations.shape} do not fit {J} joints")
        if self.root_positions.shape != (T, 3):
            raise ValueError(f"motion {self.name!r}: root positions {self.root_positions.shape} != ({T}, 3)")

    def __len__(self) -> int:
        return self.rotations.shape[0]

    @property
    def duration(self) -> float:
        return len(self) / self.fps

    def fk(self) -> tuple[np.ndarray, np.ndarray]:
        """Global rotations (T, J, 4) and positions (T, J, 3)."""
        return _fk.fk(self.rotations, self.root_positions, self.skeleton.parents, self.skeleton.offsets)

    def positions(self) -> np.ndarray:
        return self.fk()[1]

    def continuous(self) -> Motion:
        """Quaternions sign-flipped to be continuous in time (unit-normalised)."""
        return replace(self, rotations=quat_continuity(quat_normalize(self.rotations), axis=0))

    def slice(self, start: int, stop: int) -> Motion:
        return replace(
            self, rotations=self.rotations[start:stop], root_positions=self.root_positions[start:stop]
        )


def resample(motion: Motion, fps: float) -> Motion:
    """The motion at another frame rate (SLERP / LERP between source frames)."""
    if fps == motion.fps:
        return motion
    T = len(motion)
    n = int(np.floor((T - 1) * fps / motion.fps + 1e-9)) + 1
    u = np.arange(n) * motion.fps / fps
    i0 = np.minimum(np.floor(u).astype(int), T - 1)
    i1 = np.minimum(i0 + 1, T - 1)
    w = u - i0
    rot = slerp_pairs(motion.rotations[i0], motion.rotations[i1], w[:, None]).astype(np.float32)
    pos = (1 - w[:, None]) * motion.root_positions[i0] + w[:, None] * motion.root_positions[i1]
    return Motion(motion.skeleton, rot, pos, fps, motion.name)
