"""A rig as the adaptation sees it: a skeleton's joints and its rest and bind poses, plain
arrays with no file format behind them (a USD shot's character is one, pipeline.usd.read)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Rig:
    """Joints in parent-first order; quaternions xyzw, matrices in the column convention."""

    joints: tuple[str, ...]  # joint tokens ("Hips/Spine")
    names: tuple[str, ...]  # leaf names
    parents: np.ndarray  # (J,)
    rest_rot: np.ndarray  # (J, 4) local rest rotations
    rest_trans: np.ndarray  # (J, 3) local rest translations
    bind_rot: np.ndarray  # (J, 4) skeleton-space bind pose
    bind_pos: np.ndarray  # (J, 3)
    skel_to_world: np.ndarray  # (4, 4) skeleton space to world (up axis and units apart)
