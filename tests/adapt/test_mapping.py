"""Joint mapping: every naming convention on its full hierarchy, sanitised names, missing joints,
the error message."""

import re

import numpy as np
import pytest
from usd_fixtures import CMU_CLIP, ELEPHANT

from pipeline.adapt.conventions import CONVENTIONS
from pipeline.adapt.mapping import (
    LIMBS,
    MODEL_JOINTS,
    REQUIRED,
    MappingError,
    map_joints,
    map_joints_info,
)

_SIDE = {"L": {"{L}": "L", "{l}": "l", "{Left}": "Left"}, "R": {"{L}": "R", "{l}": "r", "{Left}": "Right"}}


def _side(text, s):
    for ph, v in _SIDE[s].items():
        text = text.replace(ph, v)
    return text


def _rig(edges, sanitise=None):
    """(joints as USD paths, parents) from "child parent" lines, {L} lines once per side."""
    pairs = []
    for line in edges:
        child, _, parent = line.partition(" < ")
        sides = "LR" if "{" in line else "-"
        pairs += [(_side(child, s), _side(parent, s)) if s != "-" else (child, parent) for s in sides]
    if sanitise:
        pairs = [(sanitise(c), sanitise(p) if p else p) for c, p in pairs]
    names = [c for c, _ in pairs]
    parents = np.array([names.index(p) if p else -1 for _, p in pairs])
    paths = []
    for j, n in enumerate(names):
        paths.append(f"{paths[parents[j]]}/{n}" if parents[j] >= 0 else n)
    return tuple(paths), parents


def _expected(spec, sanitise=None):
    out = {}
    for m, rig in spec.items():
        for s in "LR" if m in LIMBS else "-":
            key, name = (f"{m}_{s}", _side(rig, s)) if s != "-" else (m, rig)
            out[key] = sanitise(name) if sanitise else name
    return out


def _names(joints, roles):
    return {m: joints[i].rsplit("/", 1)[-1] for m, i in roles.items()}


def _mixamo_edges(p=""):
    return [f"{p}Hips < ", f"{p}Spine < {p}Hips", f"{p}Spine1 < {p}Spine", f"{p}Spine2 < {p}Spine1",
            f"{p}Neck < {p}Spine2", f"{p}Head < {p}Neck", f"{p}HeadTop_End < {p}Head",
            f"{p}{{Left}}Eye < {p}Head", f"{p}{{Left}}Shoulder < {p}Spine2",
            f"{p}{{Left}}Arm < {p}{{Left}}Shoulder", f"{p}{{Left}}ForeArm < {p}{{Left}}Arm",
            f"{p}{{Left}}Hand < {p}{{Left}}ForeArm", f"{p}{{Left}}HandThumb1 < {p}{{Left}}Hand",
            f"{p}{{Left}}HandThumb2 < {p}{{Left}}HandThumb1", f"{p}{{Left}}HandIndex1 < {p}{{Left}}Hand",
            f"{p}{{Left}}HandIndex2 < {p}{{Left}}HandIndex1", f"{p}{{Left}}HandIndex3 < {p}{{Left}}HandIndex2",
            f"{p}{{Left}}HandIndex4 < {p}{{Left}}HandIndex3", f"{p}{{Left}}UpLeg < {p}Hips",
            f"{p}{{Left}}Leg < {p}{{Left}}UpLeg", f"{p}{{Left}}Foot < {p}{{Left}}Leg",
            f"{p}{{Left}}ToeBase < {p}{{Left}}Foot", f"{p}{{Left}}Toe_End < {p}{{Left}}ToeBase"]  # fmt: skip


_MIXAMO_ROLES = {"Hips": "Hips", "Spine": "Spine", "Chest": "Spine2", "Neck": "Neck", "Head": "Head",
                 "Shoulder": "{Left}Shoulder", "UpperArm": "{Left}Arm", "LowerArm": "{Left}ForeArm",
                 "Hand": "{Left}Hand", "UpperLeg": "{Left}UpLeg", "LowerLeg": "{Left}Leg", "Foot": "{Left}Foot",
                 "Toes": "{Left}ToeBase"}  # fmt: skip

# convention, its full hierarchy ("child < parent"), the roles it must map to.
CASES = {
    "bandai": (
        ["Hips < ", "Spine < Hips", "Chest < Spine", "Neck < Chest", "Head < Neck", "Shoulder_{L} < Chest",
         "UpperArm_{L} < Shoulder_{L}", "LowerArm_{L} < UpperArm_{L}", "Hand_{L} < LowerArm_{L}",
         "UpperLeg_{L} < Hips", "LowerLeg_{L} < UpperLeg_{L}", "Foot_{L} < LowerLeg_{L}", "Toes_{L} < Foot_{L}"],
        {m: m for m in ("Hips", "Spine", "Chest", "Neck", "Head")} | {r: f"{r}_{{L}}" for r in LIMBS},
    ),
    "mixamo": (_mixamo_edges("mixamorig:"), {m: "mixamorig:" + r for m, r in _MIXAMO_ROLES.items()}),
    "humanik": (
        ["Reference < ", "Character1_Hips < Reference", "Character1_Spine < Character1_Hips",
         "Character1_Spine1 < Character1_Spine", "Character1_Spine2 < Character1_Spine1",
         "Character1_Spine3 < Character1_Spine2", "Character1_Neck < Character1_Spine3",
         "Character1_Neck1 < Character1_Neck", "Character1_Head < Character1_Neck1",
         "Character1_{Left}Shoulder < Character1_Spine3", "Character1_{Left}Arm < Character1_{Left}Shoulder",
         "Character1_{Left}ArmRoll < Character1_{Left}Arm", "Character1_{Left}ForeArm < Character1_{Left}Arm",
         "Character1_{Left}ForeArmRoll < Character1_{Left}ForeArm",
         "Character1_{Left}Hand < Character1_{Left}ForeArm", "Character1_{Left}HandThumb1 < Character1_{Left}Hand",
         "Character1_{Left}HandMiddle1 < Character1_{Left}Hand", "Character1_{Left}UpLeg < Character1_Hips",
         "Character1_{Left}UpLegRoll < Character1_{Left}UpLeg", "Character1_{Left}Leg < Character1_{Left}UpLeg",
         "Character1_{Left}LegRoll < Character1_{Left}Leg", "Character1_{Left}Foot < Character1_{Left}Leg",
         "Character1_{Left}ToeBase < Character1_{Left}Foot"],
        {"Hips": "Character1_Hips", "Spine": "Character1_Spine", "Chest": "Character1_Spine3",
         "Neck": "Character1_Neck", "Head": "Character1_Head", "Shoulder": "Character1_{Left}Shoulder",
         "UpperArm": "Character1_{Left}Arm", "LowerArm": "Character1_{Left}ForeArm",
         "Hand": "Character1_{Left}Hand", "UpperLeg": "Character1_{Left}UpLeg", "LowerLeg": "Character1_{Left}Leg",
         "Foot": "Character1_{Left}Foot", "Toes": "Character1_{Left}ToeBase"},
    ),
    "ue_mannequin": (
        ["root < ", "pelvis < root", "spine_01 < pelvis", "spine_02 < spine_01", "spine_03 < spine_02",
         "spine_04 < spine_03", "spine_05 < spine_04", "neck_01 < spine_05", "neck_02 < neck_01", "head < neck_02",
         "clavicle_{l} < spine_05", "upperarm_{l} < clavicle_{l}", "upperarm_twist_01_{l} < upperarm_{l}",
         "upperarm_twist_02_{l} < upperarm_{l}", "lowerarm_{l} < upperarm_{l}",
         "lowerarm_twist_01_{l} < lowerarm_{l}", "hand_{l} < lowerarm_{l}", "index_metacarpal_{l} < hand_{l}",
         "index_01_{l} < index_metacarpal_{l}", "thumb_01_{l} < hand_{l}", "thigh_{l} < pelvis",
         "thigh_twist_01_{l} < thigh_{l}", "calf_{l} < thigh_{l}", "calf_twist_01_{l} < calf_{l}",
         "foot_{l} < calf_{l}", "ball_{l} < foot_{l}", "ik_foot_root < root", "ik_foot_{l} < ik_foot_root",
         "ik_hand_root < root", "ik_hand_gun < ik_hand_root", "ik_hand_{l} < ik_hand_gun"],
        {"Hips": "pelvis", "Spine": "spine_01", "Chest": "spine_05", "Neck": "neck_01", "Head": "head",
         "Shoulder": "clavicle_{l}", "UpperArm": "upperarm_{l}", "LowerArm": "lowerarm_{l}", "Hand": "hand_{l}",
         "UpperLeg": "thigh_{l}", "LowerLeg": "calf_{l}", "Foot": "foot_{l}", "Toes": "ball_{l}"},
    ),
    "rigify": (
        ["root < ", "spine < root", "spine.001 < spine", "spine.002 < spine.001", "spine.003 < spine.002",
         "spine.004 < spine.003", "spine.005 < spine.004", "spine.006 < spine.005", "face < spine.006",
         "breast.{L} < spine.003", "pelvis.{L} < spine", "shoulder.{L} < spine.003",
         "upper_arm.{L} < shoulder.{L}", "forearm.{L} < upper_arm.{L}", "hand.{L} < forearm.{L}",
         "palm.01.{L} < hand.{L}", "f_index.01.{L} < palm.01.{L}", "thumb.01.{L} < hand.{L}",
         "thigh.{L} < spine", "shin.{L} < thigh.{L}", "foot.{L} < shin.{L}", "toe.{L} < foot.{L}",
         "heel.02.{L} < foot.{L}"],
        {"Hips": "spine", "Spine": "spine.001", "Chest": "spine.003", "Neck": "spine.004", "Head": "spine.006",
         "Shoulder": "shoulder.{L}", "UpperArm": "upper_arm.{L}", "LowerArm": "forearm.{L}", "Hand": "hand.{L}",
         "UpperLeg": "thigh.{L}", "LowerLeg": "shin.{L}", "Foot": "foot.{L}", "Toes": "toe.{L}"},
    ),
    "rigify_def": (  # generated deform bones: twist segments (.001) between upper and lower limbs
        ["DEF-spine < ", "DEF-spine.001 < DEF-spine", "DEF-spine.002 < DEF-spine.001",
         "DEF-spine.003 < DEF-spine.002", "DEF-spine.004 < DEF-spine.003", "DEF-spine.005 < DEF-spine.004",
         "DEF-spine.006 < DEF-spine.005", "DEF-shoulder.{L} < DEF-spine.003",
         "DEF-upper_arm.{L} < DEF-shoulder.{L}", "DEF-upper_arm.{L}.001 < DEF-upper_arm.{L}",
         "DEF-forearm.{L} < DEF-upper_arm.{L}.001", "DEF-forearm.{L}.001 < DEF-forearm.{L}",
         "DEF-hand.{L} < DEF-forearm.{L}.001", "DEF-thigh.{L} < DEF-spine", "DEF-thigh.{L}.001 < DEF-thigh.{L}",
         "DEF-shin.{L} < DEF-thigh.{L}.001", "DEF-shin.{L}.001 < DEF-shin.{L}", "DEF-foot.{L} < DEF-shin.{L}.001",
         "DEF-toe.{L} < DEF-foot.{L}"],
        {"Hips": "DEF-spine", "Spine": "DEF-spine.001", "Chest": "DEF-spine.003", "Neck": "DEF-spine.004",
         "Head": "DEF-spine.006", "Shoulder": "DEF-shoulder.{L}", "UpperArm": "DEF-upper_arm.{L}",
         "LowerArm": "DEF-forearm.{L}", "Hand": "DEF-hand.{L}", "UpperLeg": "DEF-thigh.{L}",
         "LowerLeg": "DEF-shin.{L}", "Foot": "DEF-foot.{L}", "Toes": "DEF-toe.{L}"},
    ),
    "daz": (  # Poser / Genesis 1-2
        ["hip < ", "abdomen < hip", "chest < abdomen", "neck < chest", "head < neck", "{l}Eye < head",
         "{l}Collar < chest", "{l}Shldr < {l}Collar", "{l}ForeArm < {l}Shldr", "{l}Hand < {l}ForeArm",
         "{l}Thumb1 < {l}Hand", "{l}Index1 < {l}Hand", "{l}Index2 < {l}Index1", "{l}Buttock < hip",
         "{l}Thigh < {l}Buttock", "{l}Shin < {l}Thigh", "{l}Foot < {l}Shin", "{l}Toe < {l}Foot"],
        {"Hips": "hip", "Spine": "abdomen", "Chest": "chest", "Neck": "neck", "Head": "head",
         "Shoulder": "{l}Collar", "UpperArm": "{l}Shldr", "LowerArm": "{l}ForeArm", "Hand": "{l}Hand",
         "UpperLeg": "{l}Thigh", "LowerLeg": "{l}Shin", "Foot": "{l}Foot", "Toes": "{l}Toe"},
    ),
    "daz_genesis": (  # Genesis 3/8: bend and twist bones, pelvis above the thighs
        ["hip < ", "pelvis < hip", "{l}ThighBend < pelvis", "{l}ThighTwist < {l}ThighBend",
         "{l}Shin < {l}ThighTwist", "{l}Foot < {l}Shin", "{l}Metatarsals < {l}Foot", "{l}Toe < {l}Metatarsals",
         "{l}BigToe < {l}Toe", "abdomenLower < hip", "abdomenUpper < abdomenLower", "chestLower < abdomenUpper",
         "chestUpper < chestLower", "{l}Pectoral < chestUpper", "{l}Collar < chestUpper",
         "{l}ShldrBend < {l}Collar", "{l}ShldrTwist < {l}ShldrBend", "{l}ForearmBend < {l}ShldrTwist",
         "{l}ForearmTwist < {l}ForearmBend", "{l}Hand < {l}ForearmTwist", "{l}Carpal1 < {l}Hand",
         "{l}Index1 < {l}Carpal1", "neckLower < chestUpper", "neckUpper < neckLower", "head < neckUpper",
         "lowerJaw < head"],
        {"Hips": "hip", "Spine": "abdomenLower", "Chest": "chestUpper", "Neck": "neckLower", "Head": "head",
         "Shoulder": "{l}Collar", "UpperArm": "{l}ShldrBend", "LowerArm": "{l}ForearmBend", "Hand": "{l}Hand",
         "UpperLeg": "{l}ThighBend", "LowerLeg": "{l}Shin", "Foot": "{l}Foot", "Toes": "{l}Toe"},
    ),
    "cmu": (
        ["Hips < ", "{L}HipJoint < Hips", "{Left}UpLeg < {L}HipJoint", "{Left}Leg < {Left}UpLeg",
         "{Left}Foot < {Left}Leg", "{Left}ToeBase < {Left}Foot", "LowerBack < Hips", "Spine < LowerBack",
         "Spine1 < Spine", "Neck < Spine1", "Neck1 < Neck", "Head < Neck1", "{Left}Shoulder < Spine1",
         "{Left}Arm < {Left}Shoulder", "{Left}ForeArm < {Left}Arm", "{Left}Hand < {Left}ForeArm",
         "{Left}FingerBase < {Left}Hand", "{Left}HandIndex1 < {Left}FingerBase", "{L}Thumb < {Left}Hand"],
        {"Hips": "Hips", "Spine": "LowerBack", "Chest": "Spine1", "Neck": "Neck", "Head": "Head",
         "Shoulder": "{Left}Shoulder", "UpperArm": "{Left}Arm", "LowerArm": "{Left}ForeArm", "Hand": "{Left}Hand",
         "UpperLeg": "{Left}UpLeg", "LowerLeg": "{Left}Leg", "Foot": "{Left}Foot", "Toes": "{Left}ToeBase"},
    ),
    "biped": (  # thighs hang off the spine, clavicles off the neck (so Chest is Bip01 Neck)
        ["Bip01 < ", "Bip01 Pelvis < Bip01", "Bip01 Spine < Bip01 Pelvis", "Bip01 Spine1 < Bip01 Spine",
         "Bip01 Neck < Bip01 Spine1", "Bip01 Head < Bip01 Neck", "Bip01 HeadNub < Bip01 Head",
         "Bip01 {L} Clavicle < Bip01 Neck", "Bip01 {L} UpperArm < Bip01 {L} Clavicle",
         "Bip01 {L} Forearm < Bip01 {L} UpperArm", "Bip01 {L} Hand < Bip01 {L} Forearm",
         "Bip01 {L} Finger0 < Bip01 {L} Hand", "Bip01 {L} Thigh < Bip01 Spine", "Bip01 {L} Calf < Bip01 {L} Thigh",
         "Bip01 {L} Foot < Bip01 {L} Calf", "Bip01 {L} Toe0 < Bip01 {L} Foot", "Bip01 {L} Toe0Nub < Bip01 {L} Toe0"],
        {"Hips": "Bip01 Pelvis", "Spine": "Bip01 Spine", "Chest": "Bip01 Neck", "Head": "Bip01 Head",
         "Shoulder": "Bip01 {L} Clavicle", "UpperArm": "Bip01 {L} UpperArm", "LowerArm": "Bip01 {L} Forearm",
         "Hand": "Bip01 {L} Hand", "UpperLeg": "Bip01 {L} Thigh", "LowerLeg": "Bip01 {L} Calf",
         "Foot": "Bip01 {L} Foot", "Toes": "Bip01 {L} Toe0"},
    ),
}  # fmt: skip


def _usd_name(name):
    """What a USD converter writes for a name (only letters, digits and _ are valid)."""
    return re.sub(r"[^0-9A-Za-z_]", "_", name)


@pytest.mark.parametrize("sanitise", [None, _usd_name], ids=["as-authored", "usd-sanitised"])
@pytest.mark.parametrize("case", list(CASES))
def test_each_convention_maps_its_full_hierarchy(case, sanitise):
    edges, spec = CASES[case]
    joints, parents = _rig(edges, sanitise)
    info = map_joints_info(joints, parents)
    assert _names(joints, info.roles) == _expected(spec, sanitise)
    assert info.convention == {"rigify_def": "rigify", "daz_genesis": "daz"}.get(case, case)
    assert info.missing == tuple(m for m in MODEL_JOINTS if m not in info.roles)
    assert map_joints(joints, parents) == info.roles


@pytest.mark.parametrize("prefix", ["mixamorig:", "mixamorig_", "mixamorig1:", "mixamorig2_", ""])
def test_mixamo_prefixes(prefix):
    joints, parents = _rig(_mixamo_edges(prefix))
    info = map_joints_info(joints, parents)
    assert _names(joints, info.roles) == _expected({m: prefix + r for m, r in _MIXAMO_ROLES.items()})
    assert info.convention == "mixamo" and info.missing == ()


def test_sanitised_names_and_namespaces():
    # Rigify with "_" for "." (spine_001, thigh_L), a Maya namespace on HumanIK names.
    edges, spec = CASES["rigify"]
    under = lambda n: n.replace(".", "_")  # noqa: E731
    joints, parents = _rig(edges, under)
    assert _names(joints, map_joints(joints, parents)) == _expected(spec, under)
    assert joints[2].endswith("/spine_001") and any(j.endswith("/thigh_L") for j in joints)
    joints, parents = _rig([e for e in _mixamo_edges("Hero:") if "End" not in e and "Eye" not in e])
    assert _names(joints, map_joints(joints, parents))["UpperLeg_R"] == "Hero:RightUpLeg"


def test_character_creator_rig_from_the_cmu_iclone_data():
    from pipeline.motion.bvh import read_bvh

    sk = read_bvh(CMU_CLIP).skeleton
    assert len(sk.names) == 100 and "CC_Base_L_UpperarmTwist01" in sk.names
    info = map_joints_info(sk.names, sk.parents)
    want = {"Hips": "CC_Base_Hip", "Spine": "CC_Base_Waist", "Chest": "CC_Base_Spine02",
            "Neck": "CC_Base_NeckTwist01", "Head": "CC_Base_Head", "Shoulder": "CC_Base_{L}_Clavicle",
            "UpperArm": "CC_Base_{L}_Upperarm", "LowerArm": "CC_Base_{L}_Forearm", "Hand": "CC_Base_{L}_Hand",
            "UpperLeg": "CC_Base_{L}_Thigh", "LowerLeg": "CC_Base_{L}_Calf", "Foot": "CC_Base_{L}_Foot",
            "Toes": "CC_Base_{L}_ToeBase"}  # fmt: skip
    assert _names(sk.names, info.roles) == _expected(want)
    assert info.convention == "character_creator" and info.missing == ()


def test_elephant_mixamo_names_map_by_name():
    """Names alone map the elephant as a human; retarget's pose check is what refuses it."""
    from pipeline.usd.read import read_shot

    c = next(c for c in read_shot(ELEPHANT).characters if c.skel_path.endswith("Elefant/_skel"))
    info = map_joints_info(c.joints, c.parents)
    assert info.convention == "mixamo" and info.missing == ("Toes_L", "Toes_R")
    want = {m: "mixamorig_" + r for m, r in _MIXAMO_ROLES.items() if m != "Toes"}
    assert _names(c.joints, info.roles) == _expected(want)


def test_ties_go_to_the_fixed_order_and_extras_break_them():
    # Bare HumanIK/Mixamo/CMU names, no joint only one of them knows: the first in CONVENTIONS.
    bare = [e for e in _mixamo_edges() if not any(w in e for w in ("End", "Eye", "Thumb", "Index"))]
    joints, parents = _rig(bare)
    order = list(CONVENTIONS)
    assert map_joints_info(joints, parents).convention == "mixamo"
    assert order.index("mixamo") < order.index("humanik") < order.index("cmu")
    # Character1_ prefix or roll bones → HumanIK; LHipJoint / LowerBack → CMU.
    joints, parents = _rig(bare + ["{Left}ArmRoll < {Left}Arm"])
    assert map_joints_info(joints, parents).convention == "humanik"
    joints, parents = _rig(CASES["cmu"][0])
    assert map_joints_info(joints, parents).convention == "cmu"


def _drop(edges, *leaves):
    """The hierarchy without the joints whose (side-template) names start with one of leaves."""
    return [e for e in edges if not e.split(" < ")[0].startswith(leaves)]


@pytest.mark.parametrize(
    "case, drop, missing",
    [
        ("cmu", ("{Left}Hand", "{Left}FingerBase", "{L}Thumb"), ("Hand_L", "Hand_R")),
        ("ue_mannequin", ("ball_",), ("Toes_L", "Toes_R")),
        ("daz", ("{l}Collar",), ("Shoulder_L", "Shoulder_R")),
        ("rigify", ("hand.", "palm", "f_index", "thumb", "toe.", "shoulder."),
         ("Shoulder_L", "Hand_L", "Shoulder_R", "Hand_R", "Toes_L", "Toes_R")),
    ],
)  # fmt: skip
def test_missing_hands_toes_shoulders_map_without_them(case, drop, missing):
    edges, spec = CASES[case]
    kept = _drop(edges, *drop)
    if drop == ("{l}Collar",):  # the arms hang off the chest directly
        kept = [e.replace("< {l}Collar", "< chest") for e in kept]
    if "shoulder." in drop:
        kept = [e.replace("< shoulder.{L}", "< spine.003") for e in kept]
    joints, parents = _rig(kept)
    info = map_joints_info(joints, parents)
    assert info.missing == missing
    want = _expected(spec)
    assert _names(joints, info.roles) == {m: n for m, n in want.items() if m not in missing}


def test_no_neck_no_spine_and_a_head_found_from_the_topology():
    # Hips → Chest → Head: no Spine, no Neck.
    edges = [e.replace("Head < Neck", "Head < Chest") for e in CASES["bandai"][0] if not e.startswith("Neck")]
    edges = [e.replace("Chest < Spine", "Chest < Hips") for e in edges if not e.startswith("Spine")]
    joints, parents = _rig(edges)
    info = map_joints_info(joints, parents)
    assert info.missing == ("Spine", "Neck") and _names(joints, info.roles)["Head"] == "Head"
    # No joint named head: the top of the chain above the chest that is not an arm.
    mix = _mixamo_edges()
    for head, edges in (
        (
            "face",
            [e.replace("Head", "face") for e in mix if "Eye" not in e],
        ),  # face → faceTop_End: not the end
        ("head_end", [e for e in mix if "Head" not in e] + ["head_end < Neck"]),
        ("skull", [e.replace("Head", "skull") for e in mix if "End" not in e and "Eye" not in e]),
    ):
        joints, parents = _rig(edges)
        roles = _names(joints, map_joints(joints, parents))
        assert roles["Head"] == head, edges
        assert roles["Neck"] == "Neck" and roles["Chest"] == "Spine2"


def test_error_names_model_joints_rig_joints_and_the_mapping_line():
    edges = [e.replace("{Left}Arm", "{l}ArmUp") for e in _mixamo_edges()]
    joints, parents = _rig(edges)
    with pytest.raises(MappingError) as ei:
        map_joints(joints, parents)
    msg = str(ei.value)
    assert msg == (
        "joints do not map onto the model skeleton: no UpperArm_L, UpperArm_R (names read as Mixamo); "
        "rig joints not placed: lArmUp, rArmUp; write them in a --mapping JSON file: "
        '{"UpperArm_L": "<rig joint>", "UpperArm_R": "<rig joint>"}'
    )
    # The line it shows is what fixes it.
    roles = map_joints(joints, parents, {"UpperArm_L": "lArmUp", "UpperArm_R": "rArmUp"})
    assert joints[roles["UpperArm_L"]].endswith("/lArmUp") and len(roles) == 21


def test_error_lists_the_likeliest_rig_joints_first_on_one_line():
    # A rig of its own names: the list is short, most like the missing joints first.
    edges = ["root < ", "body < root", "torso < body", "skull < torso"]
    for s in ("l", "r"):
        edges += [f"arm_up_{s} < torso", f"arm_low_{s} < arm_up_{s}", f"leg_up_{s} < body",
                  f"leg_low_{s} < leg_up_{s}", f"paw_{s} < leg_low_{s}"]  # fmt: skip
    edges += [f"tail{i} < {'body' if i == 0 else f'tail{i - 1}'}" for i in range(8)]
    joints, parents = _rig(edges)
    with pytest.raises(MappingError) as ei:
        map_joints(joints, parents)
    msg = str(ei.value)
    assert "\n" not in msg and "train" not in msg
    head, listed, line = msg.split("; ")
    assert head == "joints do not map onto the model skeleton: no " + ", ".join(REQUIRED)
    names = listed.removeprefix("rig joints not placed: ").split(", ")
    assert names[-1] == "… (13 more)" and len(names) == 9  # 22 joints, root known (UE), 8 shown
    assert {"arm_up_l", "arm_up_r", "leg_up_l", "leg_up_r"} <= set(names) and "tail7" not in names
    assert (
        line
        == "write them in a --mapping JSON file: {"
        + ", ".join(f'"{m}": "<rig joint>"' for m in REQUIRED)
        + "}"
    )


def test_chain_and_shared_joint_checks():
    joints, parents = _rig(CASES["bandai"][0])
    with pytest.raises(
        MappingError, match=r"'LowerArm_L' \(Hand_L\) does not descend from 'Hand_L' \(LowerArm_L\)"
    ):
        map_joints(joints, parents, {"LowerArm_L": "Hand_L", "Hand_L": "LowerArm_L"})
    with pytest.raises(
        MappingError, match="two model joints map onto the same rig joint: Neck and Head onto 'Head'"
    ):
        map_joints(joints, parents, {"Neck": "Head"})
    # null in the mapping file leaves a model joint out, even one the topology would find.
    info = map_joints_info(joints, parents, {"Neck": None, "Hand_R": None})
    assert info.missing == ("Neck", "Hand_R")


def test_conventions_are_well_formed():
    from pipeline.adapt.mapping import _compiled

    centre = {m for m in MODEL_JOINTS if m.rpartition("_")[2] not in "LR"}
    for name, c in CONVENTIONS.items():
        assert set(c) == {"label", "prefixes", "roles", "torso", "extras"}, name
        assert set(c["roles"]) <= centre | set(LIMBS) and {"Hips", "Head", "UpperArm"} <= set(c["roles"])
        for role, pats in c["roles"].items():
            for p in pats:
                assert ("{" in p.replace("{n}", "")) == (role in LIMBS), (name, p)
        _compiled(name)  # every pattern compiles
