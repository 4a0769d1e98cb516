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

_SIDE = {"L": {"{L}": "L", "{l}": "l", "{Left}": "Left", "{left}": "left"},
         "R": {"{L}": "R", "{l}": "r", "{Left}": "Right", "{left}": "right"}}  # fmt: skip


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
    "unity": (  # a Unity humanoid (HumanBodyBones names), as VRM 1.0 names them too
        ["Root < ", "Hips < Root", "Spine < Hips", "Chest < Spine", "UpperChest < Chest", "Neck < UpperChest",
         "Head < Neck", "Jaw < Head", "{Left}Eye < Head", "{Left}Shoulder < UpperChest",
         "{Left}UpperArm < {Left}Shoulder", "{Left}LowerArm < {Left}UpperArm", "{Left}Hand < {Left}LowerArm",
         "{Left}ThumbProximal < {Left}Hand", "{Left}LittleProximal < {Left}Hand",
         "{Left}LittleIntermediate < {Left}LittleProximal", "{Left}UpperLeg < Hips",
         "{Left}LowerLeg < {Left}UpperLeg", "{Left}Foot < {Left}LowerLeg", "{Left}Toes < {Left}Foot"],
        {"Hips": "Hips", "Spine": "Spine", "Chest": "UpperChest", "Neck": "Neck", "Head": "Head",
         "Shoulder": "{Left}Shoulder", "UpperArm": "{Left}UpperArm", "LowerArm": "{Left}LowerArm",
         "Hand": "{Left}Hand", "UpperLeg": "{Left}UpperLeg", "LowerLeg": "{Left}LowerLeg", "Foot": "{Left}Foot",
         "Toes": "{Left}Toes"},
    ),
    "vrm": (  # VRoid Studio's export: J_Bip_ body, J_Adj_ helpers, J_Sec_ spring bones
        ["Root < ", "J_Bip_C_Hips < Root", "J_Bip_C_Spine < J_Bip_C_Hips", "J_Bip_C_Chest < J_Bip_C_Spine",
         "J_Bip_C_UpperChest < J_Bip_C_Chest", "J_Bip_C_Neck < J_Bip_C_UpperChest", "J_Bip_C_Head < J_Bip_C_Neck",
         "J_Adj_{L}_FaceEye < J_Bip_C_Head", "J_Sec_Hair1_01 < J_Bip_C_Head",
         "J_Bip_{L}_Shoulder < J_Bip_C_UpperChest", "J_Bip_{L}_UpperArm < J_Bip_{L}_Shoulder",
         "J_Bip_{L}_LowerArm < J_Bip_{L}_UpperArm", "J_Bip_{L}_Hand < J_Bip_{L}_LowerArm",
         "J_Bip_{L}_Thumb1 < J_Bip_{L}_Hand", "J_Bip_{L}_Index1 < J_Bip_{L}_Hand",
         "J_Bip_{L}_UpperLeg < J_Bip_C_Hips", "J_Bip_{L}_LowerLeg < J_Bip_{L}_UpperLeg",
         "J_Bip_{L}_Foot < J_Bip_{L}_LowerLeg", "J_Bip_{L}_ToeBase < J_Bip_{L}_Foot"],
        {"Hips": "J_Bip_C_Hips", "Spine": "J_Bip_C_Spine", "Chest": "J_Bip_C_UpperChest", "Neck": "J_Bip_C_Neck",
         "Head": "J_Bip_C_Head", "Shoulder": "J_Bip_{L}_Shoulder", "UpperArm": "J_Bip_{L}_UpperArm",
         "LowerArm": "J_Bip_{L}_LowerArm", "Hand": "J_Bip_{L}_Hand", "UpperLeg": "J_Bip_{L}_UpperLeg",
         "LowerLeg": "J_Bip_{L}_LowerLeg", "Foot": "J_Bip_{L}_Foot", "Toes": "J_Bip_{L}_ToeBase"},
    ),
    "xsens": (  # MVN's 23 segments
        ["Pelvis < ", "L5 < Pelvis", "L3 < L5", "T12 < L3", "T8 < T12", "Neck < T8", "Head < Neck",
         "{Left}Shoulder < T8", "{Left}UpperArm < {Left}Shoulder", "{Left}ForeArm < {Left}UpperArm",
         "{Left}Hand < {Left}ForeArm", "{Left}UpperLeg < Pelvis", "{Left}LowerLeg < {Left}UpperLeg",
         "{Left}Foot < {Left}LowerLeg", "{Left}Toe < {Left}Foot"],
        {"Hips": "Pelvis", "Spine": "L5", "Chest": "T8", "Neck": "Neck", "Head": "Head",
         "Shoulder": "{Left}Shoulder", "UpperArm": "{Left}UpperArm", "LowerArm": "{Left}ForeArm",
         "Hand": "{Left}Hand", "UpperLeg": "{Left}UpperLeg", "LowerLeg": "{Left}LowerLeg", "Foot": "{Left}Foot",
         "Toes": "{Left}Toe"},
    ),
    "rokoko": (  # Rokoko Studio's export
        ["Root < ", "Hips < Root", "Spine1 < Hips", "Spine2 < Spine1", "Spine3 < Spine2", "Spine4 < Spine3",
         "Neck < Spine4", "Head < Neck", "{Left}Shoulder < Spine4", "{Left}Arm < {Left}Shoulder",
         "{Left}ForeArm < {Left}Arm", "{Left}Hand < {Left}ForeArm", "{Left}ThumbProximal < {Left}Hand",
         "{Left}Thigh < Hips", "{Left}Shin < {Left}Thigh", "{Left}Foot < {Left}Shin", "{Left}Toe < {Left}Foot",
         "{Left}ToeTip < {Left}Toe"],
        {"Hips": "Hips", "Spine": "Spine1", "Chest": "Spine4", "Neck": "Neck", "Head": "Head",
         "Shoulder": "{Left}Shoulder", "UpperArm": "{Left}Arm", "LowerArm": "{Left}ForeArm", "Hand": "{Left}Hand",
         "UpperLeg": "{Left}Thigh", "LowerLeg": "{Left}Shin", "Foot": "{Left}Foot", "Toes": "{Left}Toe"},
    ),
    "optitrack": (  # Motive's skeleton, its asset name before every bone
        ["Skeleton1_Hip < ", "Skeleton1_Ab < Skeleton1_Hip", "Skeleton1_Chest < Skeleton1_Ab",
         "Skeleton1_Neck < Skeleton1_Chest", "Skeleton1_Head < Skeleton1_Neck",
         "Skeleton1_{L}Shoulder < Skeleton1_Chest", "Skeleton1_{L}UArm < Skeleton1_{L}Shoulder",
         "Skeleton1_{L}FArm < Skeleton1_{L}UArm", "Skeleton1_{L}Hand < Skeleton1_{L}FArm",
         "Skeleton1_{L}Thumb1 < Skeleton1_{L}Hand", "Skeleton1_{L}Thigh < Skeleton1_Hip",
         "Skeleton1_{L}Shin < Skeleton1_{L}Thigh", "Skeleton1_{L}Foot < Skeleton1_{L}Shin",
         "Skeleton1_{L}Toe < Skeleton1_{L}Foot"],
        {"Hips": "Skeleton1_Hip", "Spine": "Skeleton1_Ab", "Chest": "Skeleton1_Chest", "Neck": "Skeleton1_Neck",
         "Head": "Skeleton1_Head", "Shoulder": "Skeleton1_{L}Shoulder", "UpperArm": "Skeleton1_{L}UArm",
         "LowerArm": "Skeleton1_{L}FArm", "Hand": "Skeleton1_{L}Hand", "UpperLeg": "Skeleton1_{L}Thigh",
         "LowerLeg": "Skeleton1_{L}Shin", "Foot": "Skeleton1_{L}Foot", "Toes": "Skeleton1_{L}Toe"},
    ),
    "smpl": (  # SMPL-X's body joints (SMPL says Pelvis, L_Hip, L_Knee)
        ["root < ", "pelvis < root", "{left}_hip < pelvis", "{left}_knee < {left}_hip",
         "{left}_ankle < {left}_knee", "{left}_foot < {left}_ankle", "spine1 < pelvis", "spine2 < spine1",
         "spine3 < spine2", "neck < spine3", "head < neck", "jaw < head", "{left}_eye_smplhf < head",
         "{left}_collar < spine3", "{left}_shoulder < {left}_collar", "{left}_elbow < {left}_shoulder",
         "{left}_wrist < {left}_elbow", "{left}_index1 < {left}_wrist", "{left}_thumb1 < {left}_wrist"],
        {"Hips": "pelvis", "Spine": "spine1", "Chest": "spine3", "Neck": "neck", "Head": "head",
         "Shoulder": "{left}_collar", "UpperArm": "{left}_shoulder", "LowerArm": "{left}_elbow",
         "Hand": "{left}_wrist", "UpperLeg": "{left}_hip", "LowerLeg": "{left}_knee", "Foot": "{left}_ankle",
         "Toes": "{left}_foot"},
    ),
    "advanced_skeleton": (  # Maya's Advanced Skeleton deform joints
        ["Root_M < ", "Hip_{L} < Root_M", "HipPart1_{L} < Hip_{L}", "Knee_{L} < HipPart1_{L}",
         "Ankle_{L} < Knee_{L}", "Toes_{L} < Ankle_{L}", "ToesEnd_{L} < Toes_{L}", "Spine1_M < Root_M",
         "Chest_M < Spine1_M", "Neck_M < Chest_M", "Head_M < Neck_M", "HeadEnd_M < Head_M", "Jaw_M < Head_M",
         "Scapula_{L} < Chest_M", "Shoulder_{L} < Scapula_{L}", "ShoulderPart1_{L} < Shoulder_{L}",
         "Elbow_{L} < ShoulderPart1_{L}", "Wrist_{L} < Elbow_{L}", "IndexFinger1_{L} < Wrist_{L}",
         "Cup_{L} < Wrist_{L}"],
        {"Hips": "Root_M", "Spine": "Spine1_M", "Chest": "Chest_M", "Neck": "Neck_M", "Head": "Head_M",
         "Shoulder": "Scapula_{L}", "UpperArm": "Shoulder_{L}", "LowerArm": "Elbow_{L}", "Hand": "Wrist_{L}",
         "UpperLeg": "Hip_{L}", "LowerLeg": "Knee_{L}", "Foot": "Ankle_{L}", "Toes": "Toes_{L}"},
    ),
    "lafan1": (  # LaFAN1's BVH files
        ["Hips < ", "{Left}UpLeg < Hips", "{Left}Leg < {Left}UpLeg", "{Left}Foot < {Left}Leg",
         "{Left}Toe < {Left}Foot", "Spine < Hips", "Spine1 < Spine", "Spine2 < Spine1", "Neck < Spine2",
         "Head < Neck", "{Left}Shoulder < Spine2", "{Left}Arm < {Left}Shoulder", "{Left}ForeArm < {Left}Arm",
         "{Left}Hand < {Left}ForeArm"],
        {**_MIXAMO_ROLES, "Toes": "{Left}Toe"},
    ),
    "makehuman": (  # MakeHuman's default skeleton (MPFB in Blender)
        ["root < ", "spine05 < root", "spine04 < spine05", "spine03 < spine04", "spine02 < spine03",
         "spine01 < spine02", "neck01 < spine01", "neck02 < neck01", "neck03 < neck02", "head < neck03",
         "jaw < head", "clavicle.{L} < spine01", "shoulder01.{L} < clavicle.{L}",
         "upperarm01.{L} < shoulder01.{L}", "upperarm02.{L} < upperarm01.{L}",
         "lowerarm01.{L} < upperarm02.{L}", "lowerarm02.{L} < lowerarm01.{L}", "wrist.{L} < lowerarm02.{L}",
         "metacarpal1.{L} < wrist.{L}", "finger2-1.{L} < metacarpal1.{L}", "pelvis.{L} < root",
         "upperleg01.{L} < pelvis.{L}", "upperleg02.{L} < upperleg01.{L}", "lowerleg01.{L} < upperleg02.{L}",
         "lowerleg02.{L} < lowerleg01.{L}", "foot.{L} < lowerleg02.{L}", "toe1-1.{L} < foot.{L}",
         "toe1-2.{L} < toe1-1.{L}", "toe2-1.{L} < foot.{L}"],
        {"Hips": "root", "Spine": "spine05", "Chest": "spine01", "Neck": "neck01", "Head": "head",
         "Shoulder": "clavicle.{L}", "UpperArm": "upperarm01.{L}", "LowerArm": "lowerarm01.{L}",
         "Hand": "wrist.{L}", "UpperLeg": "upperleg01.{L}", "LowerLeg": "lowerleg01.{L}", "Foot": "foot.{L}",
         "Toes": "toe1-1.{L}"},
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
    # Upper arms no convention names, and hands that no word shows: nothing places the arms.
    edges = [e.replace("{Left}Arm", "{l}ArmUp").replace("{Left}Hand", "{l}Paw") for e in _mixamo_edges()]
    joints, parents = _rig(edges)
    with pytest.raises(MappingError) as ei:
        map_joints(joints, parents)
    msg = str(ei.value)
    assert msg == (
        "joints do not map onto the model skeleton: no UpperArm_L, UpperArm_R (names read as Mixamo); "
        "rig joints not placed: lArmUp, rArmUp, lPaw, rPaw, lPawThumb1, rPawThumb1, lPawThumb2, rPawThumb2, "
        '… (8 more); write them in a --mapping JSON file: {"UpperArm_L": "<rig joint>", "UpperArm_R": "<rig joint>"}'
    )
    # The line it shows is what fixes it.
    roles = map_joints(joints, parents, {"UpperArm_L": "lArmUp", "UpperArm_R": "rArmUp"})
    assert joints[roles["UpperArm_L"]].endswith("/lArmUp") and len(roles) == 19  # no hands


def test_a_limb_no_convention_names_is_placed_from_its_words_and_chain():
    # Mixamo's upper arms renamed: the hands say where the arms end, the chain down to them
    # from the chest holds them (pipeline.adapt.chains), the rest stays Mixamo's.
    edges = [e.replace("{Left}Arm", "{l}ArmUp") for e in _mixamo_edges()]
    joints, parents = _rig(edges)
    info = map_joints_info(joints, parents)
    assert info.convention == "mixamo" and info.missing == ()
    assert _names(joints, info.roles) == _expected(_MIXAMO_ROLES | {"UpperArm": "{l}ArmUp"})


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
    # The limbs lead (their names are like the missing joints'), none of the tail.
    limbs = {f"{j}_{s}" for j in ("arm_up", "arm_low", "leg_up", "leg_low", "paw") for s in "lr"}
    assert set(names[:8]) <= limbs and {"arm_up_l", "arm_up_r"} <= set(names)
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
        # Hips may come from the topology alone (MakeHuman's "root" is too common a name to take).
        assert set(c["roles"]) <= centre | set(LIMBS) and {"Head", "UpperArm"} <= set(c["roles"])
        for role, pats in c["roles"].items():
            for p in pats:
                assert ("{" in p.replace("{n}", "")) == (role in LIMBS), (name, p)
        _compiled(name)  # every pattern compiles


# A studio's own naming (no convention's): side prefixes, a _jnt suffix, twist joints inside
# the chains, a clavicle called "clav", the upper arm called "shoulder".
_STUDIO = ["root < ", "C_pelvis_jnt < root", "C_spine1_jnt < C_pelvis_jnt", "C_spine2_jnt < C_spine1_jnt",
           "C_chest_jnt < C_spine2_jnt", "C_neck_jnt < C_chest_jnt", "C_head_jnt < C_neck_jnt",
           "C_headEnd_jnt < C_head_jnt", "{L}_clav_jnt < C_chest_jnt", "{L}_shoulder_jnt < {L}_clav_jnt",
           "{L}_shoulderTwist_jnt < {L}_shoulder_jnt", "{L}_elbow_jnt < {L}_shoulderTwist_jnt",
           "{L}_wrist_jnt < {L}_elbow_jnt", "{L}_index1_jnt < {L}_wrist_jnt", "{L}_thigh_jnt < C_pelvis_jnt",
           "{L}_knee_jnt < {L}_thigh_jnt", "{L}_ankle_jnt < {L}_knee_jnt", "{L}_ball_jnt < {L}_ankle_jnt",
           "{L}_heel_jnt < {L}_ankle_jnt"]  # fmt: skip


def test_a_studio_rig_of_its_own_naming_maps_from_words_and_chains():
    joints, parents = _rig(_STUDIO)
    info = map_joints_info(joints, parents)
    want = {"Hips": "C_pelvis_jnt", "Spine": "C_spine1_jnt", "Chest": "C_chest_jnt", "Neck": "C_neck_jnt",
            "Head": "C_head_jnt", "Shoulder": "{L}_clav_jnt", "UpperArm": "{L}_shoulder_jnt",
            "LowerArm": "{L}_elbow_jnt", "Hand": "{L}_wrist_jnt", "UpperLeg": "{L}_thigh_jnt",
            "LowerLeg": "{L}_knee_jnt", "Foot": "{L}_ankle_jnt", "Toes": "{L}_ball_jnt"}  # fmt: skip
    assert _names(joints, info.roles) == _expected(want)
    # Sides as words anywhere, camel case, a namespace: the same joints.
    renamed = [re.sub(r"\{L\}_(\w)", lambda m: "Hero:{Left}" + m[1].upper(), e).replace("C_", "Hero:")
               for e in _STUDIO]  # fmt: skip
    joints, parents = _rig(renamed)
    got = _names(joints, map_joints(joints, parents))
    assert got["UpperArm_R"] == "Hero:RightShoulder_jnt" and got["Toes_L"] == "Hero:LeftBall_jnt"
    assert got["Head"] == "Hero:head_jnt" and got["Hips"] == "Hero:pelvis_jnt"


def _quadruped():
    edges = ["root < ", "body < root", "neck < body", "head < neck"]
    for p in ("front", "back"):
        for s in "lr":
            edges += [
                f"{p}_upper_{s} < body",
                f"{p}_lower_{s} < {p}_upper_{s}",
                f"{p}_paw_{s} < {p}_lower_{s}",
            ]
    return edges


def _one_hand():
    """The studio rig with a left "paw" for a hand: only the right hand has a hand word."""
    edges = [e for e in _STUDIO if "wrist" not in e and "index1" not in e]
    return edges + ["L_paw_jnt < L_elbow_jnt", "L_index1_jnt < L_paw_jnt", "R_wrist_jnt < R_elbow_jnt",
                    "R_index1_jnt < R_wrist_jnt"]  # fmt: skip


@pytest.mark.parametrize("what", ["no hands", "one hand", "a quadruped"])
def test_words_and_chains_place_nothing_they_cannot_see(what):
    from pipeline.adapt import chains

    edges = {
        "no hands": [e.replace("wrist", "paw") for e in _STUDIO],
        "one hand": _one_hand(),
        "a quadruped": _quadruped(),
    }[what]
    joints, parents = _rig(edges)
    assert chains.limbs(joints, parents) == {}
    with pytest.raises(MappingError, match="joints do not map onto the model skeleton"):
        map_joints(joints, parents)
