"""Motion core: skeletons, clips, rotations, forward kinematics, BVH."""

from pipeline.motion.clip import Motion
from pipeline.motion.skeleton import Skeleton

__all__ = ["Motion", "Skeleton"]
