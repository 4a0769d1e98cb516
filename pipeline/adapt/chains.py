"""Limbs of a rig no naming convention names, from its words and its chains.

Studio rigs often name joints their own way (``L_thigh_jnt``, ``arm_up_L_bind``,
``lf_knee``). Where no convention of :mod:`pipeline.adapt.conventions` places the limbs,
the names still say two things reliably: the side (a ``l``/``left``/``lf`` word, or a
``l``/``r`` glued before a capital: ``lThigh``) and which joint ends a limb (``hand`` or
``wrist``; ``foot`` or ``ankle``). The chain from the joint both hands (or feet) branch
from down to each hand (or foot) then holds the limb, read from its end up: the lower
limb (a ``forearm``/``elbow``/``shin``/``knee``… word, else the end's parent), the upper
limb (an ``upperarm``/``thigh``… word, else the lower limb's parent), and for an arm the
joint above the upper arm, when the chain has one, as the shoulder. Twist, roll and helper
joints (their words say so) are never taken. The toes are the foot's child on a toe word,
or its only child that is not an end site. Nothing is placed unless both sides' hands and
feet are found; the hips, spine, chest, neck and head then come from the topology as for
every convention (:mod:`pipeline.adapt.mapping`).
"""

from __future__ import annotations

import re

import numpy as np

from pipeline.adapt.hierarchy import common_ancestor, depths, path_below

_LEFT = frozenset({"l", "left", "lf", "lft"})
_RIGHT = frozenset({"r", "right", "rt", "rgt"})
#: Words of joints that are never a limb's own (twist and helper bones, end sites, rig controls).
_SKIP = frozenset(
    {"twist", "roll", "part", "helper", "corrective", "correct", "share", "end", "nub", "tip", "ik", "fk",
     "ctrl", "target", "pole", "null", "offset", "extra", "jiggle", "muscle", "fan"}
)  # fmt: skip
_END = frozenset({"end", "nub", "tip", "top"})
_HAND = frozenset({"hand", "wrist"})
_FOOT = frozenset({"foot", "ankle"})
_TOES = frozenset({"toe", "toes", "ball", "toebase"})
# A limb's lower and upper segments: single words, and pairs of words read as one.
_LOWER = {
    "arm": (frozenset({"forearm", "lowerarm", "elbow", "radius", "ulna", "lowarm", "loarm"}),
            (("lower", "arm"), ("low", "arm"), ("fore", "arm"), ("arm", "low"), ("arm", "lower"))),
    "leg": (frozenset({"shin", "calf", "knee", "lowerleg", "tibia", "crus", "lowleg", "loleg"}),
            (("lower", "leg"), ("low", "leg"), ("leg", "low"), ("leg", "lower"))),
}  # fmt: skip
_UPPER = {
    "arm": (frozenset({"upperarm", "uparm", "humerus", "bicep"}),
            (("upper", "arm"), ("up", "arm"), ("arm", "up"), ("arm", "upper"))),
    "leg": (frozenset({"thigh", "upleg", "upperleg", "femur"}),
            (("upper", "leg"), ("up", "leg"), ("leg", "up"), ("leg", "upper"))),
}  # fmt: skip
#: Upper-limb words that name other joints in some rigs (a Mixamo arm, a pelvis-side hip):
#: taken only where no joint of the limb has one of the words above.
_UPPER_WEAK = {"arm": frozenset({"arm"}), "leg": frozenset({"hip"})}
_CAMEL = re.compile(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+|\d+")


def words(name: str) -> list[str]:
    """The leaf name's words, lower case: split at every other character than letters and
    digits and at case changes (``lThighBend`` → l, thigh, bend; ``L_UpArm`` → l, up, arm);
    a Maya namespace is dropped."""
    leaf = name.rsplit("/", 1)[-1].rsplit(":", 1)[-1]
    return [w.lower() for part in re.split(r"[^0-9A-Za-z]+", leaf) for w in _CAMEL.findall(part)]


def side(ws: list[str]) -> str | None:
    """ "L", "R" or None: a side word anywhere (``l_thigh``, ``DEF-thigh.L.001``, ``LeftThigh``,
    ``Hero_L_thigh``); None where there are both. Only joints with a hand or foot word are
    asked, so ``L5`` (a spine joint) never matters."""
    found = {s for w in ws for s, words_ in (("L", _LEFT), ("R", _RIGHT)) if w in words_}
    return found.pop() if len(found) == 1 else None


#: An end site's name ending, glued or not (``headend``, ``HeadTop_End``, ``head_nub``, ``Tip2``).
_END_TAIL = re.compile(r"(end|nub|top|tip)\d*$", re.I)


def end_site(name: str) -> bool:
    """Whether a joint's name says it is an end site: an end word (``C_headEnd_jnt``,
    ``head_nub``) or an end glued to its last word (``headend``)."""
    return bool(_END_TAIL.search(name)) or any(w in _END for w in words(name))


def _has(ws: list[str], single: frozenset, pairs=()) -> bool:
    return any(w in single for w in ws) or any(p in zip(ws, ws[1:], strict=False) for p in pairs)


def _ends(ws_of: list[list[str]], depth: np.ndarray, kind: frozenset) -> dict[str, int]:
    """Per side, the shallowest joint with a ``kind`` word and no skip word."""
    out: dict[str, int] = {}
    for j, ws in enumerate(ws_of):
        s = side(ws)
        if s and _has(ws, kind) and not _has(ws, _SKIP) and (s not in out or depth[j] < depth[out[s]]):
            out[s] = j
    return out


def _limb(ws_of, path: list[int], limb: str) -> tuple[int | None, int | None]:
    """(upper, lower) joints of one limb's ``path`` (top first, the hand or foot last)."""
    body = [j for j in path[:-1] if not _has(ws_of[j], _SKIP)]
    if not body:
        return None, None
    lower = next((j for j in body if _has(ws_of[j], *_LOWER[limb])), body[-1])
    above = body[: body.index(lower)]
    upper = next((j for j in above if _has(ws_of[j], *_UPPER[limb])), None)
    upper = (
        upper if upper is not None else next((j for j in above if _has(ws_of[j], _UPPER_WEAK[limb])), None)
    )
    upper = upper if upper is not None else (above[-1] if above else None)
    return upper, lower


def limbs(names, parents: np.ndarray) -> dict[str, int]:
    """Model joint (``UpperArm_L``…, ``Toes_R``) → rig joint index for the limbs, or {} where
    the names do not show both hands and both feet with their sides."""
    parents = np.asarray(parents)
    ws_of = [words(n) for n in names]
    depth = depths(parents)
    hands, feet = _ends(ws_of, depth, _HAND), _ends(ws_of, depth, _FOOT)
    if set(hands) != {"L", "R"} or set(feet) != {"L", "R"}:
        return {}
    arms_top = common_ancestor(parents, [hands["L"], hands["R"]])
    legs_top = common_ancestor(parents, [feet["L"], feet["R"]])
    if arms_top is None or legs_top is None:
        return {}
    out: dict[str, int] = {}
    children: dict[int, list[int]] = {}
    for j, p in enumerate(parents):
        children.setdefault(int(p), []).append(j)
    for s in "LR":
        arm = path_below(parents, arms_top, hands[s])
        upper, lower = _limb(ws_of, arm, "arm")
        if upper is None:
            return {}
        out |= {f"UpperArm_{s}": upper, f"LowerArm_{s}": lower, f"Hand_{s}": hands[s]}
        above = [j for j in arm[: arm.index(upper)] if not _has(ws_of[j], _SKIP)]
        if above:
            out[f"Shoulder_{s}"] = above[-1]
        leg = path_below(parents, legs_top, feet[s])
        upper, lower = _limb(ws_of, leg, "leg")
        if upper is None:
            return {}
        out |= {f"UpperLeg_{s}": upper, f"LowerLeg_{s}": lower, f"Foot_{s}": feet[s]}
        kids = [c for c in children.get(feet[s], []) if not _has(ws_of[c], _SKIP)]
        toes = [c for c in kids if _has(ws_of[c], _TOES)] or (kids if len(kids) == 1 else [])
        if toes:
            out[f"Toes_{s}"] = toes[0]
    return out
