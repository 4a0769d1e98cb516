"""Blender's rigs map by themselves: Rigify and its common variants (pelvis- or spine-rooted,
with or without a root bone, DEF-/ORG- prefixes, ``.L`` or USD's ``_L``), the hips found
where the legs and the spine branch; refused only with no humanoid reading, naming the part."""

import re

import numpy as np
import pytest

from pipeline.adapt.mapping import MappingError, map_joints_info


def _rig(edges: list[str], prefix: str = "", usd: bool = False):
    """(joint paths, parents) from "child < parent" lines; ``{s}`` lines once per side."""
    pairs = []
    for line in edges:
        child, _, parent = line.partition(" < ")
        for s in "LR" if "{s}" in line else "-":
            pairs.append((child.replace("{s}", s), parent.replace("{s}", s)))

    def name(n):
        n = n if n == "root" or not n else prefix + n
        return re.sub(r"[^0-9A-Za-z_]", "_", n) if usd else n

    names = [name(c) for c, _ in pairs]
    parents = np.array([names.index(name(p)) if p else -1 for _, p in pairs])
    paths: list[str] = []
    for j, n in enumerate(names):
        paths.append(f"{paths[parents[j]]}/{n}" if parents[j] >= 0 else n)
    return tuple(paths), parents


_UPPER = ["spine.001 < spine", "spine.002 < spine.001", "spine.003 < spine.002", "neck < spine.003",
          "head < neck", "shoulder.{s} < spine.003", "upper_arm.{s} < shoulder.{s}",
          "forearm.{s} < upper_arm.{s}", "hand.{s} < forearm.{s}"]  # fmt: skip
_LEGS = ["thigh.{s} < {hips}", "shin.{s} < thigh.{s}", "foot.{s} < shin.{s}", "toe.{s} < foot.{s}"]


def _legs(hips):
    return [e.replace("{hips}", hips) for e in _LEGS]


# variant: (edges, the rig joint that is the hips)
VARIANTS = {
    # the rig: pelvis at the root, thighs on it beside the spine chain
    "pelvis-rooted": (["pelvis < ", "spine < pelvis", *_UPPER, *_legs("pelvis")], "pelvis"),
    "pelvis-under-root": (
        ["root < ", "pelvis < root", "spine < pelvis", *_UPPER, *_legs("pelvis")],
        "pelvis",
    ),
    # the metarig's own layout: spine is the hips, thighs on it
    "spine-rooted": (["spine < ", *_UPPER, *_legs("spine")], "spine"),
    "spine-under-root": (["root < ", "spine < root", *_UPPER, *_legs("spine")], "spine"),
    # the legs hang off a bone the names do not know, the spine off it too
    "unnamed-hips": (["root < ", "torso < root", "spine < torso", *_UPPER, *_legs("torso")], "torso"),
}


@pytest.mark.parametrize("usd", [False, True], ids=["blender-names", "usd-sanitised"])
@pytest.mark.parametrize("prefix", ["", "DEF-", "ORG-"])
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_rigify_variants_map_without_a_mapping_file(variant, prefix, usd):
    edges, hips = VARIANTS[variant]
    joints, parents = _rig(edges, prefix, usd)
    info = map_joints_info(joints, parents)
    names = {m: joints[i].rsplit("/", 1)[-1] for m, i in info.roles.items()}
    fix = (lambda n: re.sub(r"[^0-9A-Za-z_]", "_", prefix + n)) if usd else (lambda n: prefix + n)
    assert info.convention == "rigify" and info.missing == ()
    assert names["Hips"] == fix(hips)
    # the spine joint above the hips, the chest where the arms join, the neck and head by topology
    want_spine = "spine.001" if hips == "spine" else "spine"
    assert names["Spine"] == fix(want_spine) and names["Chest"] == fix("spine.003")
    assert names["Neck"] == fix("neck") and names["Head"] == fix("head")
    for s in "LR":
        assert names[f"UpperLeg_{s}"] == fix(f"thigh.{s}") and names[f"Toes_{s}"] == fix(f"toe.{s}")
        assert names[f"Shoulder_{s}"] == fix(f"shoulder.{s}") and names[f"Hand_{s}"] == fix(f"hand.{s}")


def test_a_hips_named_by_the_mapping_file_is_taken_as_it_is():
    joints, parents = _rig(VARIANTS["pelvis-rooted"][0])
    with pytest.raises(
        MappingError, match=r"joint 'thigh.L' \(UpperLeg_L\) does not descend from 'spine' \(Hips\)"
    ):
        map_joints_info(joints, parents, {"Hips": "spine"})


def test_a_named_hips_the_legs_and_spine_descend_from_is_kept():
    # Biped-like: thighs off the first spine joint. Rigify names that joint (spine) the hips and
    # both legs and the chest descend from it, so the pelvis above it does not take its place.
    edges = ["pelvis < ", "spine < pelvis", *_UPPER, *_legs("spine")]
    joints, parents = _rig(edges)
    names = {m: joints[i].rsplit("/", 1)[-1] for m, i in map_joints_info(joints, parents).roles.items()}
    assert names["Hips"] == "spine" and names["Spine"] == "spine.001"


@pytest.mark.parametrize(
    "edges, says",
    [
        # no legs at all: the missing model joints are named
        (["pelvis < ", "spine < pelvis", *_UPPER], r"no UpperLeg_L, LowerLeg_L, Foot_L, UpperLeg_R"),
        # legs and arms in two separate hierarchies
        (["spine < ", *_UPPER, "pelvis < ", *_legs("pelvis")], r"no hips: the legs and the arms are not in one"),
        # arms hang from where the legs do: no spine between hips and chest
        (
            ["pelvis < ", "shoulder.{s} < pelvis", "upper_arm.{s} < shoulder.{s}", "forearm.{s} < upper_arm.{s}",
             "hand.{s} < forearm.{s}", "head < pelvis", *_legs("pelvis")],
            r"the arms do not join the spine above the hips",
        ),
    ],
    ids=["no-legs", "two-hierarchies", "arms-on-the-hips"],
)  # fmt: skip
def test_refused_only_without_a_humanoid_reading_and_says_which_part(edges, says):
    joints, parents = _rig(edges)
    with pytest.raises(MappingError, match=says):
        map_joints_info(joints, parents)
