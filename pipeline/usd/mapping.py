"""Mapping a rig's joints onto the model skeleton's 21 joints.

Exact names first, then name conventions (Bandai, Character Creator ``CC_Base_*``, Mixamo
``mixamorig:*`` / ``mixamorig_*``, HumanIK ``LeftUpLeg``), then a JSON override file
``{"<model joint>": "<rig joint name or path>" | null}``. The torso is found from the
topology (chest = the lowest common ancestor of the arms), so the number of spine
joints a rig has does not matter. Hand-written: no maintained package maps skeletons by
name conventions.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

MODEL_JOINTS = (
    "Hips", "Spine", "Chest", "Neck", "Head",
    "Shoulder_L", "UpperArm_L", "LowerArm_L", "Hand_L",
    "Shoulder_R", "UpperArm_R", "LowerArm_R", "Hand_R",
    "UpperLeg_L", "LowerLeg_L", "Foot_L", "Toes_L",
    "UpperLeg_R", "LowerLeg_R", "Foot_R", "Toes_R",
)  # fmt: skip
REQUIRED = ("Hips", "Head") + tuple(
    f"{r}_{s}" for s in "LR" for r in ("UpperArm", "LowerArm", "Hand", "UpperLeg", "LowerLeg", "Foot")
)
# Words (side tokens removed, lower case, joined) that name each limb role.
_LIMB_WORDS = {
    "Shoulder": ("shoulder", "clavicle", "collar", "collarbone"),
    "UpperArm": ("upperarm", "arm", "uparm"),
    "LowerArm": ("lowerarm", "forearm", "elbow"),
    "Hand": ("hand", "wrist"),
    "UpperLeg": ("upperleg", "upleg", "thigh", "hip"),
    "LowerLeg": ("lowerleg", "leg", "calf", "shin", "knee"),
    "Foot": ("foot", "ankle"),
    "Toes": ("toes", "toe", "toebase", "ball"),
}
_CENTRE_WORDS = {"Hips": ("hips", "hip", "pelvis"), "Head": ("head",)}
_PREFIX = re.compile(r"^(mixamorig\d*[:_]|cc_base_|bip\d*[ _]|.*:)", re.I)
# Chains whose joints must descend from each other (parent role, child role).
_CHAINS = [("Hips", "UpperLeg_{s}"), ("UpperLeg_{s}", "LowerLeg_{s}"), ("LowerLeg_{s}", "Foot_{s}"),
           ("Foot_{s}", "Toes_{s}"), ("Shoulder_{s}", "UpperArm_{s}"), ("UpperArm_{s}", "LowerArm_{s}"),
           ("LowerArm_{s}", "Hand_{s}"), ("Hips", "Head")]  # fmt: skip


class MappingError(Exception):
    """The rig's joints cannot be mapped onto the model skeleton (message says why)."""


def _tokens(name: str) -> tuple[str | None, str]:
    """(side "L"/"R"/None, role word) of a joint name."""
    base = _PREFIX.sub("", name)
    parts = [p for p in re.split(r"[_\.\-\s]+|(?<=[a-z0-9])(?=[A-Z])", base) if p]
    words = [p.lower() for p in parts]
    side = None
    rest = []
    for w in words:
        if w in ("l", "left") and side is None:
            side = "L"
        elif w in ("r", "right") and side is None:
            side = "R"
        else:
            rest.append(w)
    return side, "".join(rest)


def _depths(parents: np.ndarray) -> np.ndarray:
    d = np.zeros(len(parents), np.int64)
    for j, p in enumerate(parents):
        d[j] = d[p] + 1 if p >= 0 else 0
    return d


def _ancestors(parents, j) -> list[int]:
    out = []
    while j >= 0:
        out.append(int(j))
        j = parents[j]
    return out  # j, parent, …, root


def load_override(path: str | Path | None) -> dict[str, str | None]:
    if not path:
        return {}
    try:
        d = json.loads(Path(path).read_text())
    except (OSError, ValueError) as e:
        raise MappingError(f"mapping file {path}: {e}") from None
    if not isinstance(d, dict) or any(k not in MODEL_JOINTS for k in d):
        bad = [k for k in d if k not in MODEL_JOINTS] if isinstance(d, dict) else ["(not an object)"]
        raise MappingError(
            f"mapping file {path}: unknown model joint(s) {bad}; expected {list(MODEL_JOINTS)}"
        )
    return d


def map_joints(
    joints: tuple[str, ...], parents: np.ndarray, override: dict[str, str | None] | None = None
) -> dict[str, int]:
    """Model joint name → rig joint index for every joint that maps."""
    names = [t.rsplit("/", 1)[-1] for t in joints]
    depth = _depths(parents)
    out: dict[str, int] = {}
    exact = {n: i for i, n in enumerate(names)}
    for m in MODEL_JOINTS:
        if m in exact:
            out[m] = exact[m]
    if not all(r in out for r in REQUIRED):
        out = {}
        cands: dict[str, list[int]] = {}
        for i, n in enumerate(names):
            side, word = _tokens(n)
            if side is None:
                for role, words in _CENTRE_WORDS.items():
                    if word in words:
                        cands.setdefault(role, []).append(i)
            else:
                for role, words in _LIMB_WORDS.items():
                    if word in words:
                        cands.setdefault(f"{role}_{side}", []).append(i)
        for role, idx in cands.items():
            out[role] = min(idx, key=lambda i: (depth[i], i))  # the one nearest the root
    for role, target in (override or {}).items():
        if target is None:
            out.pop(role, None)
            continue
        hit = [i for i, (t, n) in enumerate(zip(joints, names, strict=False)) if target in (t, n)]
        if not hit:
            raise MappingError(f"mapping override {role} -> {target!r}: no such joint in the skeleton")
        out[role] = hit[0]
    _torso(out, parents)
    missing = [r for r in REQUIRED if r not in out]
    if missing:
        raise MappingError(
            f"joints do not map onto the model skeleton: no {', '.join(missing)} "
            "(name the rig's joints in a --mapping JSON file)"
        )
    for a, b in _CHAINS:
        for s in "LR":
            ra, rb = a.format(s=s), b.format(s=s)
            if ra in out and rb in out and out[ra] not in _ancestors(parents, out[rb])[1:]:
                raise MappingError(
                    f"joint {names[out[rb]]!r} ({rb}) does not descend from {names[out[ra]]!r} ({ra})"
                )
    if len(set(out.values())) != len(out):
        raise MappingError("two model joints map onto the same rig joint")
    return out


def _torso(out: dict[str, int], parents: np.ndarray) -> None:
    """Chest, Spine and Neck from the topology when names did not give them."""
    if not all(k in out for k in ("Hips", "Head", "UpperArm_L", "UpperArm_R")):
        return
    arm_l = out.get("Shoulder_L", out["UpperArm_L"])
    arm_r = out.get("Shoulder_R", out["UpperArm_R"])
    anc_r = set(_ancestors(parents, arm_r))
    chest = next(a for a in _ancestors(parents, arm_l)[1:] if a in anc_r)
    hips, head = out["Hips"], out["Head"]
    spine_path = _ancestors(parents, chest)  # chest … root
    if hips not in spine_path or chest == hips:
        raise MappingError("the arms do not join the spine above the hips")
    out.setdefault("Chest", chest)
    below = spine_path[: spine_path.index(hips)]  # chest … first joint above hips
    if len(below) > 1:
        out.setdefault("Spine", below[-1])
    neck_path = _ancestors(parents, head)
    if chest in neck_path:
        above = neck_path[: neck_path.index(chest)]  # head … first joint above chest
        if len(above) > 1:
            out.setdefault("Neck", above[-1])
