"""Rig naming conventions the joint mapping reads without a mapping file, as plain data.

Each entry of ``CONVENTIONS`` is one convention (the dict's order breaks ties, see
``pipeline.adapt.mapping``):

- ``label``: its name in messages.
- ``prefixes``: what may precede every name (``mixamorig:``); a name matches with or without it.
- ``roles``: model joint → rig name patterns, best first. Limb roles (``UpperArm``, no side)
  carry a side placeholder and stand for both ``UpperArm_L`` and ``UpperArm_R``. Spine, Chest
  and Neck are left out on purpose: they come from the topology (Chest = the lowest common
  ancestor of the arms), whatever the number of spine joints. A convention that names them
  (the model skeleton's own) has its names taken.
- ``torso``: the convention's spine and neck joints (known, placed by the topology).
- ``extras``: other joints it knows and the model does not (roots, twist, fingers, ends).
  They are never placed; they count towards the convention's score.

Pattern syntax: ``{L}``/``{l}`` → ``L``/``R``, ``{Left}``/``{left}`` → ``Left``/``Right``,
``{n}`` → digits (maybe none), ``*`` → anything. Names are compared by their leaf name
(``Hips/Spine`` → ``Spine``), case-insensitively, with every run of characters other than
letters and digits read as ``_``: ``spine.001``, ``spine_001``, ``DEF-thigh.L``,
``DEF_thigh_L`` and ``mixamorig:Hips``, ``mixamorig_Hips`` are the same name. A Maya namespace
(``Character1:Hips``) is also tried without it.
"""

from __future__ import annotations

_FINGERS = ("Thumb", "Index", "Middle", "Ring", "Pinky")

CONVENTIONS: dict[str, dict] = {
    # The model skeleton's own names (Bandai-Namco motion dataset): an identity mapping.
    "bandai": {
        "label": "Bandai (model skeleton)",
        "prefixes": (),
        "roles": {
            "Hips": ("Hips",), "Spine": ("Spine",), "Chest": ("Chest",), "Neck": ("Neck",),
            "Head": ("Head",), "Shoulder": ("Shoulder_{L}",), "UpperArm": ("UpperArm_{L}",),
            "LowerArm": ("LowerArm_{L}",), "Hand": ("Hand_{L}",), "UpperLeg": ("UpperLeg_{L}",),
            "LowerLeg": ("LowerLeg_{L}",), "Foot": ("Foot_{L}",), "Toes": ("Toes_{L}",),
        },
        "torso": (),
        "extras": (),
    },
    # Reallusion Character Creator / iClone / ActorCore (the CMU iClone BVH rigs).
    "character_creator": {
        "label": "Character Creator",
        "prefixes": (),
        "roles": {
            "Hips": ("CC_Base_Hip",), "Head": ("CC_Base_Head",),
            "Shoulder": ("CC_Base_{L}_Clavicle",), "UpperArm": ("CC_Base_{L}_Upperarm",),
            "LowerArm": ("CC_Base_{L}_Forearm",), "Hand": ("CC_Base_{L}_Hand",),
            "UpperLeg": ("CC_Base_{L}_Thigh",), "LowerLeg": ("CC_Base_{L}_Calf",),
            "Foot": ("CC_Base_{L}_Foot",), "Toes": ("CC_Base_{L}_ToeBase",),
        },
        "torso": ("CC_Base_Waist", "CC_Base_Spine{n}", "CC_Base_NeckTwist{n}"),
        # Pelvis (legs' parent), twist and share bones, fingers, toes, face: all CC_Base_*.
        "extras": ("RL_BoneRoot", "CC_Base_BoneRoot", "CC_Base_*"),
    },
    # Mixamo (mixamorig:Hips from FBX, mixamorig_Hips from a USD converter, mixamorig1: …).
    "mixamo": {
        "label": "Mixamo",
        "prefixes": ("mixamorig{n}:",),
        "roles": {
            "Hips": ("Hips",), "Head": ("Head",),
            "Shoulder": ("{Left}Shoulder",), "UpperArm": ("{Left}Arm",), "LowerArm": ("{Left}ForeArm",),
            "Hand": ("{Left}Hand",), "UpperLeg": ("{Left}UpLeg",), "LowerLeg": ("{Left}Leg",),
            "Foot": ("{Left}Foot",), "Toes": ("{Left}ToeBase",),
        },
        "torso": ("Spine", "Spine{n}", "Neck"),
        "extras": ("HeadTop_End", "{Left}Toe_End", "{Left}Eye")
        + tuple(f"{{Left}}Hand{f}{{n}}" for f in _FINGERS),
    },
    # Autodesk HumanIK (Maya's Character1_Hips, MotionBuilder, FBX).
    "humanik": {
        "label": "HumanIK",
        "prefixes": ("Character{n}_",),
        "roles": {
            "Hips": ("Hips",), "Head": ("Head",),
            "Shoulder": ("{Left}Shoulder",), "UpperArm": ("{Left}Arm",), "LowerArm": ("{Left}ForeArm",),
            "Hand": ("{Left}Hand",), "UpperLeg": ("{Left}UpLeg",), "LowerLeg": ("{Left}Leg",),
            "Foot": ("{Left}Foot",), "Toes": ("{Left}ToeBase",),
        },
        "torso": ("Spine", "Spine{n}", "Neck", "Neck{n}"),
        "extras": ("Reference", "HipsTranslation", "{Left}ShoulderExtra", "{Left}ArmRoll", "{Left}ForeArmRoll",
                   "{Left}UpLegRoll", "{Left}LegRoll", "{Left}FootExtraFinger{n}", "{Left}HandExtraFinger{n}")
        + tuple(f"{{Left}}Hand{f}{{n}}" for f in _FINGERS)
        + tuple(f"{{Left}}InHand{f}" for f in _FINGERS)
        + tuple(f"{{Left}}Foot{f}{{n}}" for f in _FINGERS),
    },
    # Unreal Engine 5 (and 4) Mannequin.
    "ue_mannequin": {
        "label": "UE5 Mannequin",
        "prefixes": (),
        "roles": {
            "Hips": ("pelvis",), "Head": ("head",),
            "Shoulder": ("clavicle_{l}",), "UpperArm": ("upperarm_{l}",), "LowerArm": ("lowerarm_{l}",),
            "Hand": ("hand_{l}",), "UpperLeg": ("thigh_{l}",), "LowerLeg": ("calf_{l}",),
            "Foot": ("foot_{l}",), "Toes": ("ball_{l}",),
        },
        "torso": ("spine_{n}", "neck_{n}"),
        "extras": ("root", "ik_*", "interaction", "center_of_mass", "*_twist_{n}_{l}", "*_correctiveRoot_{l}",
                   "*_metacarpal_{l}", "thumb_{n}_{l}", "index_{n}_{l}", "middle_{n}_{l}", "ring_{n}_{l}",
                   "pinky_{n}_{l}", "ball_leg_{l}"),
    },
    # Blender Rigify metarig (spine = the hips, spine.003 the chest region, spine.004-.005 the
    # neck, spine.006 the head), its generated DEF- deform and ORG- original bones, and
    # converters' spine_001. Rigs that root the legs elsewhere (a pelvis) get their hips from
    # the topology (pipeline.adapt.mapping._hips).
    "rigify": {
        "label": "Rigify",
        "prefixes": ("DEF-", "ORG-"),
        "roles": {
            "Hips": ("spine",), "Head": ("spine.006",),
            "Shoulder": ("shoulder.{L}",), "UpperArm": ("upper_arm.{L}",), "LowerArm": ("forearm.{L}",),
            "Hand": ("hand.{L}",), "UpperLeg": ("thigh.{L}",), "LowerLeg": ("shin.{L}",),
            "Foot": ("foot.{L}",), "Toes": ("toe.{L}",),
        },
        "torso": ("spine.{n}",),
        "extras": ("root", "face", "pelvis.{L}", "breast.{L}", "heel.{n}.{L}", "palm.{n}.{L}",
                   "upper_arm.{L}.{n}", "forearm.{L}.{n}", "thigh.{L}.{n}", "shin.{L}.{n}",
                   "thumb.{n}.{L}", "f_index.{n}.{L}", "f_middle.{n}.{L}", "f_ring.{n}.{L}", "f_pinky.{n}.{L}"),
    },
    # DAZ Studio / Poser figures (Poser, Genesis 1-2: lThigh, lShldr; Genesis 3/8/9: lThighBend…).
    "daz": {
        "label": "DAZ/Poser",
        "prefixes": (),
        "roles": {
            "Hips": ("hip",), "Head": ("head",),
            "Shoulder": ("{l}Collar",), "UpperArm": ("{l}Shldr", "{l}ShldrBend"),
            "LowerArm": ("{l}ForeArm", "{l}ForearmBend"), "Hand": ("{l}Hand",),
            "UpperLeg": ("{l}Thigh", "{l}ThighBend"), "LowerLeg": ("{l}Shin",),
            "Foot": ("{l}Foot",), "Toes": ("{l}Toe",),
        },
        "torso": ("abdomen", "abdomen{n}", "abdomenLower", "abdomenUpper", "chest", "chest{n}", "chestLower",
                  "chestUpper", "neck", "neck{n}", "neckLower", "neckUpper"),
        "extras": ("pelvis", "{l}Buttock", "{l}ShldrTwist", "{l}ForearmTwist", "{l}ThighTwist", "{l}Metatarsals",
                   "{l}BigToe*", "{l}SmallToe*", "{l}Pectoral", "{l}Eye", "{l}Ear", "lowerJaw", "upperTeeth",
                   "lowerTeeth", "tongue*", "{l}Carpal{n}", "{l}Thumb{n}", "{l}Index{n}", "{l}Mid{n}",
                   "{l}Ring{n}", "{l}Pinky{n}", "upperFaceRig", "lowerFaceRig"),
    },
    # CMU motion capture, 31 joints (cgspeed BVH). LHipJoint is a zero-length joint between the
    # hips and LeftUpLeg, not the upper leg.
    "cmu": {
        "label": "CMU 31-joint",
        "prefixes": (),
        "roles": {
            "Hips": ("Hips",), "Head": ("Head",),
            "Shoulder": ("{Left}Shoulder",), "UpperArm": ("{Left}Arm",), "LowerArm": ("{Left}ForeArm",),
            "Hand": ("{Left}Hand",), "UpperLeg": ("{Left}UpLeg",), "LowerLeg": ("{Left}Leg",),
            "Foot": ("{Left}Foot",), "Toes": ("{Left}ToeBase",),
        },
        "torso": ("LowerBack", "Spine", "Spine1", "Neck", "Neck1"),
        "extras": ("{L}HipJoint", "{Left}FingerBase", "{Left}HandIndex1", "{L}Thumb"),
    },
    # 3ds Max Biped (Bip01 Pelvis; the thighs hang off the spine, the clavicles off the neck).
    "biped": {
        "label": "3ds Max Biped",
        "prefixes": ("Bip{n} ",),
        "roles": {
            "Hips": ("Pelvis",), "Head": ("Head",),
            "Shoulder": ("{L} Clavicle",), "UpperArm": ("{L} UpperArm",), "LowerArm": ("{L} Forearm",),
            "Hand": ("{L} Hand",), "UpperLeg": ("{L} Thigh",), "LowerLeg": ("{L} Calf",),
            "Foot": ("{L} Foot",), "Toes": ("{L} Toe0",),
        },
        "torso": ("Spine", "Spine{n}", "Neck", "Neck{n}"),
        "extras": ("Bip{n}", "{L} Finger*", "{L} Toe*", "HeadNub", "{L} ForeTwist*", "Ponytail*"),
    },
}  # fmt: skip
