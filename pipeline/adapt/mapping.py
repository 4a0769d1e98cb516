"""Mapping a rig's joints onto the model skeleton's 21 joints.

The rig's names are read against every naming convention in ``pipeline.adapt.conventions``
(the model skeleton's own Bandai names, Character Creator, Mixamo, HumanIK, UE5 Mannequin,
Rigify, DAZ/Poser, CMU, 3ds Max Biped, Unity Humanoid, VRoid/VRM, Xsens MVN, Rokoko, OptiTrack
Motive, SMPL, Advanced Skeleton, MakeHuman, LaFAN1), one data entry each; the convention that explains the
most joints names them. Then a JSON override file ``{"<model joint>": "<rig joint name or
path>" | null}``. The torso is found from the topology (chest = the lowest common ancestor of
the arms), so the number of spine joints a rig has does not matter. Hand-written: no
maintained package maps skeletons by name conventions.
"""

from __future__ import annotations

import difflib
import json
import re
from functools import cache
from pathlib import Path
from typing import NamedTuple

import numpy as np

from pipeline import jsonfile
from pipeline.adapt import chains
from pipeline.adapt.conventions import CONVENTIONS
from pipeline.adapt.hierarchy import ancestors, common_ancestor, depths
from pipeline.errors import TweenError
from pipeline.inputs import not_a_file

MODEL_JOINTS = (
    "Hips", "Spine", "Chest", "Neck", "Head",
    "Shoulder_L", "UpperArm_L", "LowerArm_L", "Hand_L",
    "Shoulder_R", "UpperArm_R", "LowerArm_R", "Hand_R",
    "UpperLeg_L", "LowerLeg_L", "Foot_L", "Toes_L",
    "UpperLeg_R", "LowerLeg_R", "Foot_R", "Toes_R",
)  # fmt: skip
# A rig without hands, toes, shoulders, neck or spine joints still maps; these it must have.
REQUIRED = ("Hips", "Head") + tuple(
    f"{r}_{s}" for s in "LR" for r in ("UpperArm", "LowerArm", "UpperLeg", "LowerLeg", "Foot")
)
LIMBS = ("Shoulder", "UpperArm", "LowerArm", "Hand", "UpperLeg", "LowerLeg", "Foot", "Toes")
# Chains whose joints must descend from each other (parent role, child role).
_CHAINS = [("Hips", "UpperLeg_{s}"), ("UpperLeg_{s}", "LowerLeg_{s}"), ("LowerLeg_{s}", "Foot_{s}"),
           ("Foot_{s}", "Toes_{s}"), ("Shoulder_{s}", "UpperArm_{s}"), ("UpperArm_{s}", "LowerArm_{s}"),
           ("LowerArm_{s}", "Hand_{s}"), ("Hips", "Head")]  # fmt: skip
_SIDES = {"L": {"{L}": "L", "{l}": "l", "{Left}": "Left", "{left}": "left"},
          "R": {"{L}": "R", "{l}": "r", "{Left}": "Right", "{left}": "right"}}  # fmt: skip
_NOT_PLACED_SHOWN = 8  # rig joints an error message lists


class MappingError(TweenError):
    """The rig's joints cannot be mapped onto the model skeleton (message says why; the
    caller that knows the file names it). ``unplaced``: the REQUIRED model joints the names
    did not place, when that is why; ``reason``: the message without ``hint`` (the
    ``--mapping`` file to write), for commands that take no mapping file."""

    def __init__(self, message: str, unplaced: tuple[str, ...] = (), hint: str | None = None):
        super().__init__(f"{message}; {hint}" if hint else message)
        self.unplaced, self.reason, self.hint = tuple(unplaced), message, hint


class JointMapping(NamedTuple):
    roles: dict[str, int]  # model joint → rig joint index
    convention: str | None  # the CONVENTIONS key that named the joints (None: none named any)
    missing: tuple[str, ...]  # model joints the rig does not have (never a REQUIRED one)


def _norm(text: str) -> str:
    """A name as compared: lower case, every run of other characters than letters/digits → ``_``."""
    return re.sub(r"[^0-9a-z]+", "_", text.lower())


def _keys(name: str) -> tuple[str, ...]:
    """The forms a rig joint's leaf name is matched in (with and without a Maya namespace)."""
    keys = [_norm(name).strip("_")]
    if ":" in name:
        keys.append(_norm(name.rsplit(":", 1)[-1]).strip("_"))
    return tuple(keys)


def _regex(pattern: str, side: str | None) -> str:
    for ph, text in _SIDES[side or "L"].items():
        if ph in pattern and side is None:
            raise ValueError(f"convention pattern {pattern!r} has a side placeholder on a centre role")
        pattern = pattern.replace(ph, text)
    parts = re.split(r"(\{n\}|\*)", pattern)
    return "".join({"{n}": r"\d*", "*": ".*"}.get(p) or re.escape(_norm(p)) for p in parts)


@cache
def _compiled(conv: str) -> tuple[list[tuple[re.Pattern, str, int]], list[re.Pattern]]:
    """(role patterns as (regex, model joint, priority) in order, other known-joint patterns)."""
    c = CONVENTIONS[conv]
    pfx = "|".join(_regex(p, None) for p in c["prefixes"])
    wrap = (lambda r: re.compile(f"(?:{pfx})?(?:{r})")) if pfx else re.compile
    roles = []
    for role, pats in c["roles"].items():
        for prio, p in enumerate(pats):
            if role in LIMBS:
                roles += [(wrap(_regex(p, s)), f"{role}_{s}", prio) for s in "LR"]
            else:
                roles.append((wrap(_regex(p, None)), role, prio))
    known = dict.fromkeys(_regex(p, s) for p in (*c["torso"], *c["extras"]) for s in "LR")
    return roles, [wrap(r) for r in known]


def _read(conv: str, names: list[str]) -> tuple[dict[str, list[tuple[int, int]]], set[int]]:
    """Under one convention: {model joint: [(priority, rig index)]}, and the rig joints it knows."""
    roles, known = _compiled(conv)
    found: dict[str, list[tuple[int, int]]] = {}
    explained: set[int] = set()
    for i, n in enumerate(names):
        keys = _keys(n)
        hit = next(((m, pr) for rx, m, pr in roles if any(rx.fullmatch(k) for k in keys)), None)
        if hit:
            found.setdefault(hit[0], []).append((hit[1], i))
            explained.add(i)
        elif any(rx.fullmatch(k) for rx in known for k in keys):
            explained.add(i)
    return found, explained


def load_override(path: str | Path | None) -> dict[str, str | None]:
    if not path:
        return {}
    if (why := not_a_file(path, "mapping file")) and Path(path).exists():  # else read_text names it
        raise MappingError(f"mapping file {path}: {why}")
    try:
        d = jsonfile.loads(Path(path).read_text())
    except (OSError, ValueError) as e:  # a key twice (DuplicateKeyError) names it and its line
        raise MappingError(f"mapping file {path}: {e}") from None
    if not isinstance(d, dict) or any(k not in MODEL_JOINTS for k in d):
        bad = [k for k in d if k not in MODEL_JOINTS] if isinstance(d, dict) else ["(not an object)"]
        raise MappingError(
            f"mapping file {path}: unknown model joint(s) {bad}; expected {list(MODEL_JOINTS)}"
        )
    return d


def map_joints(
    joints: tuple[str, ...],
    parents: np.ndarray,
    override: dict[str, str | None] | None = None,
    others: tuple[str, ...] = (),
) -> dict[str, int]:
    """Model joint name → rig joint index for every joint that maps."""
    return map_joints_info(joints, parents, override, others).roles


def _named_by(target: str, joints) -> list[int]:
    """The indices of ``joints`` an override's ``target`` names: its path, or its last name."""
    return [i for i, t in enumerate(joints) if target in (t, t.rsplit("/", 1)[-1])]


def _override_joint(role: str, target: str, joints, others) -> int:
    """The joint of ``joints`` the override ``role -> target`` names (the first); MappingError
    where none is, saying so of one under another root (``others``: map_joints_info)."""
    hit = _named_by(target, joints)
    if not hit and _named_by(target, others):
        raise MappingError(
            f"mapping override {role} -> {target!r}: a joint under another root joint than the "
            f"character's {joints[0]!r}; the fill fills the hierarchy under {joints[0]!r} and "
            "keeps the other roots' joints as authored: name a joint of that hierarchy"
        )
    if not hit:
        raise MappingError(f"mapping override {role} -> {target!r}: no such joint in the skeleton")
    return hit[0]


def map_joints_info(
    joints: tuple[str, ...],
    parents: np.ndarray,
    override: dict[str, str | None] | None = None,
    others: tuple[str, ...] = (),
) -> JointMapping:
    """The mapping, the convention that named the joints, and the model joints the rig lacks.
    ``others``: the skeleton's joints under roots other than the character's (``joints``,
    rooted at ``joints[0]``; pipeline.usd.read.character_joints), which an override names
    in vain.

    Every convention reads the names; the one that explains the most rig joints (placed or
    known as its extras) wins, then the one placing the most model joints, then the first in
    ``CONVENTIONS``. Per model joint, the first matching pattern wins, then the joint nearest
    the root. Limbs no convention places come from the rig's own words and chains
    (:func:`pipeline.adapt.chains.limbs`).
    """
    parents = np.asarray(parents)
    names = [t.rsplit("/", 1)[-1] for t in joints]
    conv, out, explained = _named(names, parents)
    removed = set()
    for role, target in (override or {}).items():
        if target is None:
            out.pop(role, None)
            removed.add(role)
            continue
        out[role] = _override_joint(role, target, joints, others)
    if "Hips" not in (override or {}):  # a hips the user named is taken as it is
        _hips(out, parents)
    _torso(out, names, parents, removed)
    missing = [r for r in REQUIRED if r not in out]
    if missing:
        reason, hint = _missing_message(missing, names, out, explained, conv)
        raise MappingError(reason, tuple(missing), hint)
    for a, b in _CHAINS:
        for s in "LR":
            ra, rb = a.format(s=s), b.format(s=s)
            if ra in out and rb in out and out[ra] not in ancestors(parents, out[rb])[1:]:
                raise MappingError(
                    f"joint {names[out[rb]]!r} ({rb}) does not descend from {names[out[ra]]!r} ({ra})"
                )
    if len(set(out.values())) != len(out):
        by_joint: dict[int, list[str]] = {}
        for m in MODEL_JOINTS:
            if m in out:
                by_joint.setdefault(out[m], []).append(m)
        i, ms = next((i, ms) for i, ms in by_joint.items() if len(ms) > 1)
        raise MappingError(
            f"two model joints map onto the same rig joint: {' and '.join(ms)} onto {names[i]!r}"
        )
    roles = {m: out[m] for m in MODEL_JOINTS if m in out}
    return JointMapping(roles, conv, tuple(m for m in MODEL_JOINTS if m not in out))


def _named(names: list[str], parents: np.ndarray) -> tuple[str | None, dict[str, int], set[int]]:
    """(the convention that names the rig, model joint → rig joint as the names place them,
    the rig joints that convention knows): see :func:`map_joints_info`."""
    depth = depths(parents)
    best = None
    for order, conv in enumerate(CONVENTIONS):
        found, explained = _read(conv, names)
        key = (-len(explained), -len(found), order)
        if best is None or key < best[0]:
            best = (key, conv, found, explained)
    _, conv, found, explained = best
    if not found:
        conv = None
    out = {m: min(c, key=lambda pi: (pi[0], depth[pi[1]], pi[1]))[1] for m, c in found.items()}
    if any(r not in out for r in REQUIRED if r not in ("Hips", "Head")):
        # No convention places every limb: the rig's own words and chains (pipeline.adapt.chains)
        # place the ones it left, never over a joint it placed.
        taken = set(out.values())
        for m, j in chains.limbs(names, parents).items():
            if m not in out and j not in taken:
                out[m] = j
    return conv, out, explained


def _missing_message(missing, names, out, explained, conv) -> tuple[str, str]:
    """The model joints not placed and the rig joints that might be them; the file to write."""
    placed = set(out.values())
    free = [i for i in range(len(names)) if i not in placed and i not in explained]
    free = free or [i for i in range(len(names)) if i not in placed]
    vocab = {m: _vocabulary(m) for m in missing}

    def likeness(i):
        k = _keys(names[i])[-1]
        return max(difflib.SequenceMatcher(None, k, w).ratio() for m in missing for w in vocab[m])

    ranked = sorted(free, key=lambda i: (-likeness(i), i))
    shown = [names[i] for i in ranked[:_NOT_PLACED_SHOWN]]
    more = len(ranked) - len(shown)
    listed = ", ".join(shown) + (f", … ({more} more)" if more > 0 else "") if shown else "none"
    read = f" (names read as {CONVENTIONS[conv]['label']})" if conv else ""
    line = json.dumps({m: "<rig joint>" for m in missing})
    return (
        f"joints do not map onto the model skeleton: no {', '.join(missing)}{read}; "
        f"rig joints not placed: {listed}",
        f"write them in a --mapping JSON file: {line}",
    )


@cache
def _vocabulary(model_joint: str) -> tuple[str, ...]:
    """Every convention's names for a model joint (compared without prefixes and wildcards)."""
    role, _, side = model_joint.partition("_")
    words = {_norm(m) for m in (model_joint, role)}
    for c in CONVENTIONS.values():
        for p in c["roles"].get(role, ()):
            for ph, text in _SIDES[side or "L"].items():
                p = p.replace(ph, text)
            words.add(_norm(p.replace("{n}", "").replace("*", "")).strip("_"))
    return tuple(sorted(words))


def _hips(out: dict[str, int], parents: np.ndarray) -> None:
    """The hips from the topology where the names' hips is not one: the joint where both legs
    and the spine (up to the chest, the arms' common ancestor) branch. A named hips that both
    legs and the chest descend from is kept (CC's and Genesis' pelvis, Biped's spine between)."""
    if not all(k in out for k in ("UpperLeg_L", "UpperLeg_R", "UpperArm_L", "UpperArm_R")):
        return  # the missing limbs are the error
    arms = [out.get(f"Shoulder_{s}", out[f"UpperArm_{s}"]) for s in "LR"]
    legs = [out["UpperLeg_L"], out["UpperLeg_R"]]
    chest = common_ancestor(parents, arms)
    branch = None if chest is None else common_ancestor(parents, [*legs, chest])
    if branch is None:
        raise MappingError(
            "no hips: the legs and the arms are not in one hierarchy (no joint both legs and the spine descend from)"
        )
    named = out.get("Hips")
    if named is not None and all(named in ancestors(parents, j)[1:] for j in (*legs, chest)):
        return
    out["Hips"] = branch


def _torso(out: dict[str, int], names: list[str], parents: np.ndarray, removed: set[str]) -> None:
    """Chest, Spine, Neck (and Head when no joint is named one) from the topology."""
    if not all(k in out for k in ("Hips", "UpperArm_L", "UpperArm_R")):
        return
    arm_l = out.get("Shoulder_L", out["UpperArm_L"])
    arm_r = out.get("Shoulder_R", out["UpperArm_R"])
    anc_r = set(ancestors(parents, arm_r))
    chest = next((a for a in ancestors(parents, arm_l)[1:] if a in anc_r), None)
    hips = out["Hips"]
    spine_path = ancestors(parents, chest) if chest is not None else []  # chest … root
    if hips not in spine_path or chest == hips:
        raise MappingError("the arms do not join the spine above the hips")
    if "Chest" not in removed:
        out.setdefault("Chest", chest)
    if "Head" not in out and "Head" not in removed:
        head = _head_from_topology(names, parents, chest, (arm_l, arm_r))
        if head is not None:
            out["Head"] = head
    below = spine_path[: spine_path.index(hips)]  # chest … first joint above hips
    if len(below) > 1 and "Spine" not in removed:
        out.setdefault("Spine", below[-1])
    if "Head" not in out:
        return
    neck_path = ancestors(parents, out["Head"])
    if chest in neck_path and "Neck" not in removed:
        above = neck_path[: neck_path.index(chest)]  # head … first joint above chest
        if len(above) > 1:
            out.setdefault("Neck", above[-1])


def _head_from_topology(names, parents: np.ndarray, chest: int, arms: tuple[int, int]) -> int | None:
    """The top of the chain above the chest that is not an arm: where it branches, or its end."""
    children: dict[int, list[int]] = {}
    for j, p in enumerate(parents):
        children.setdefault(int(p), []).append(j)
    on_arm = {a for arm in arms for a in ancestors(parents, arm)}
    size = np.ones(len(parents), np.int64)
    for j in range(len(parents) - 1, 0, -1):  # parents come before children
        if parents[j] >= 0:
            size[parents[j]] += size[j]
    kids = [c for c in children.get(chest, []) if c not in on_arm]
    if not kids:
        return None
    first = j = max(kids, key=lambda c: (size[c], -c))
    while len(children.get(j, [])) == 1:
        j = children[j][0]
    if not children.get(j) and j != first and parents[j] != first and chains.end_site(names[j]):
        j = int(parents[j])  # an end site (HeadTop_End, face_end) above the head
    return j
