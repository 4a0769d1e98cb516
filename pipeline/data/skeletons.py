"""The model's skeleton: Bandai Namco's 21 joints (joint_Root folded into Hips), shipped as JSON
so filling a shot needs no training data."""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import numpy as np

from pipeline.motion.skeleton import Skeleton

_JSON = Path(__file__).with_name("bandai_skeleton.json")

# Left/right joint pairs and the foot joints the protocol's skate metric uses.
MIRROR_PAIRS = [
    ("Shoulder_L", "Shoulder_R"),
    ("UpperArm_L", "UpperArm_R"),
    ("LowerArm_L", "LowerArm_R"),
    ("Hand_L", "Hand_R"),
    ("UpperLeg_L", "UpperLeg_R"),
    ("LowerLeg_L", "LowerLeg_R"),
    ("Foot_L", "Foot_R"),
    ("Toes_L", "Toes_R"),
]
FOOT_JOINTS = ("Foot_L", "Toes_L", "Foot_R", "Toes_R")
# Two-bone IK legs: (hip, knee, ankle, toe).
LEGS = (("UpperLeg_L", "LowerLeg_L", "Foot_L", "Toes_L"), ("UpperLeg_R", "LowerLeg_R", "Foot_R", "Toes_R"))


def skeleton_from_json(path: str | Path) -> Skeleton:
    d = json.loads(Path(path).read_text())
    names = d["names"]
    ends = {names.index(k): np.array(v, np.float32) for k, v in d.get("end_sites", {}).items()}
    return Skeleton(
        tuple(names),
        np.array(d["parents"]),
        np.array(d["offsets"], np.float32),
        d.get("up_axis", "Y"),
        d.get("meters_per_unit", 0.01),
        ends,
    )


@lru_cache(maxsize=1)
def bandai_skeleton() -> Skeleton:
    """The 21-joint skeleton every Bandai clip shares (root rest height 93 cm)."""
    return skeleton_from_json(_JSON)


@lru_cache(maxsize=1)
def bandai_mirror():
    """The Bandai skeleton's left/right mirror (reflection across the world XY plane).

    Its per-joint reflections were derived once by ``pipeline.motion.mirror.derive_mirror``
    from the train split and are stored with the skeleton; a test re-derives them.
    """
    from pipeline.motion.mirror import Mirror, find_pairs

    d = json.loads(_JSON.read_text())["mirror"]
    return Mirror(find_pairs(bandai_skeleton().names), np.array(d["signs"], np.float64), int(d["axis"]))
