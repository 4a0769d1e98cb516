"""A motion clip: local joint rotations and a root trajectory on a skeleton."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipeline.motion import fk as _fk
from pipeline.motion.rotations import quat_continuity, quat_normalize
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
