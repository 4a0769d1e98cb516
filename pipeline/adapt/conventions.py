"""Rig naming conventions the joint mapping reads without a mapping file, as plain data.

Each entry of ``CONVENTIONS`` is one convention (the dict's order breaks ties, see
``pipeline.adapt.mapping``):

- ``label``: its name in messages.
- ``prefixes``: what may precede every name (``mixamorig:``); a name matches with or without it.
- ``roles``: model joint → rig name patterns, best first. Limb roles (``UpperArm``, no side)
  carry a side placeholder and stand for both ``UpperArm_L`` and ``UpperArm_R``. Hips may be
  left out where its name is too common to take (the topology finds it). Spine, Chest
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
_UNITY_FINGERS = ("Thumb", "Index", "Middle", "Ring", "Little")  # Unity, VRM and Rokoko say Little

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
    # Unity's humanoid bone names (HumanBodyBones), as Unity rigs and VRM 1.0 models name them.
    "unity": {
        "label": "Unity Humanoid",
        "prefixes": (),
        "roles": {
            "Hips": ("Hips",), "Head": ("Head",),
            "Shoulder": ("{Left}Shoulder",), "UpperArm": ("{Left}UpperArm",), "LowerArm": ("{Left}LowerArm",),
            "Hand": ("{Left}Hand",), "UpperLeg": ("{Left}UpperLeg",), "LowerLeg": ("{Left}LowerLeg",),
            "Foot": ("{Left}Foot",), "Toes": ("{Left}Toes",),
        },
        "torso": ("Spine", "Chest", "UpperChest", "Neck"),
        "extras": ("Root", "Jaw", "{Left}Eye")
        + tuple(f"{{Left}}{f}{p}" for f in _UNITY_FINGERS for p in ("Proximal", "Intermediate", "Distal")),
    },
    # VRoid Studio / VRM 0.x (J_Bip_C_Hips, J_Bip_L_UpperLeg; J_Adj_ and J_Sec_ helper and
    # spring bones).
    "vrm": {
        "label": "VRoid / VRM 0.x",
        "prefixes": ("J_Bip_",),
        "roles": {
            "Hips": ("C_Hips",), "Head": ("C_Head",),
            "Shoulder": ("{L}_Shoulder",), "UpperArm": ("{L}_UpperArm",), "LowerArm": ("{L}_LowerArm",),
            "Hand": ("{L}_Hand",), "UpperLeg": ("{L}_UpperLeg",), "LowerLeg": ("{L}_LowerLeg",),
            "Foot": ("{L}_Foot",), "Toes": ("{L}_ToeBase",),
        },
        "torso": ("C_Spine", "C_Chest", "C_UpperChest", "C_Neck"),
        "extras": ("Root", "J_Adj_*", "J_Sec_*") + tuple(f"{{L}}_{f}{{n}}" for f in _UNITY_FINGERS),
    },
    # Xsens MVN segments (Pelvis, the L5/L3/T12/T8 spine, RightUpperLeg, RightToe).
    "xsens": {
        "label": "Xsens MVN",
        "prefixes": (),
        "roles": {
            "Hips": ("Pelvis",), "Head": ("Head",),
            "Shoulder": ("{Left}Shoulder",), "UpperArm": ("{Left}UpperArm",), "LowerArm": ("{Left}ForeArm",),
            "Hand": ("{Left}Hand",), "UpperLeg": ("{Left}UpperLeg",), "LowerLeg": ("{Left}LowerLeg",),
            "Foot": ("{Left}Foot",), "Toes": ("{Left}Toe",),
        },
        "torso": ("L5", "L3", "T12", "T8", "Neck"),
        "extras": ("{Left}Toe_End", "{Left}Hand_End") + tuple(f"{{Left}}{f}{{n}}" for f in _FINGERS),
    },
    # Rokoko Studio / Smartsuit (leftThigh, leftShin, spine1-4).
    "rokoko": {
        "label": "Rokoko",
        "prefixes": (),
        "roles": {
            "Hips": ("Hips",), "Head": ("Head",),
            "Shoulder": ("{Left}Shoulder",), "UpperArm": ("{Left}Arm",), "LowerArm": ("{Left}ForeArm",),
            "Hand": ("{Left}Hand",), "UpperLeg": ("{Left}Thigh",), "LowerLeg": ("{Left}Shin",),
            "Foot": ("{Left}Foot",), "Toes": ("{Left}Toe",),
        },
        "torso": ("Spine{n}", "Neck"),
        "extras": ("Root", "{Left}ToeTip", "{Left}Toe_End") + tuple(f"{{Left}}{f}*" for f in _UNITY_FINGERS),
    },
    # OptiTrack Motive skeletons: the asset's name, then Hip, Ab, LThigh, LUArm (Skeleton1_LThigh).
    "optitrack": {
        "label": "OptiTrack Motive",
        "prefixes": ("*_",),
        "roles": {
            "Hips": ("Hip",), "Head": ("Head",),
            "Shoulder": ("{L}Shoulder",), "UpperArm": ("{L}UArm",), "LowerArm": ("{L}FArm",),
            "Hand": ("{L}Hand",), "UpperLeg": ("{L}Thigh",), "LowerLeg": ("{L}Shin",),
            "Foot": ("{L}Foot",), "Toes": ("{L}Toe",),
        },
        "torso": ("Ab", "Chest", "Neck"),
        "extras": tuple(f"{{L}}{f}{{n}}" for f in _FINGERS),
    },
    # SMPL, SMPL-H and SMPL-X body models (L_Hip or left_hip rotates the thigh, L_Knee the shin,
    # L_Collar the clavicle, L_Shoulder the upper arm).
    "smpl": {
        "label": "SMPL / SMPL-X",
        "prefixes": (),
        "roles": {
            "Hips": ("Pelvis",), "Head": ("Head",),
            "Shoulder": ("{L}_Collar", "{left}_collar"), "UpperArm": ("{L}_Shoulder", "{left}_shoulder"),
            "LowerArm": ("{L}_Elbow", "{left}_elbow"), "Hand": ("{L}_Wrist", "{left}_wrist"),
            "UpperLeg": ("{L}_Hip", "{left}_hip"), "LowerLeg": ("{L}_Knee", "{left}_knee"),
            "Foot": ("{L}_Ankle", "{left}_ankle"), "Toes": ("{L}_Foot", "{left}_foot"),
        },
        "torso": ("Spine{n}", "Neck"),
        "extras": ("root", "Jaw", "{L}_Hand", "{left}_hand", "{left}_eye_smplhf")
        + tuple(f"{{left}}_{f.lower()}{{n}}" for f in _FINGERS),
    },
    # Advanced Skeleton (Maya): side suffixes _L/_R/_M; Shoulder_L is the upper arm, Scapula_L
    # the clavicle, Hip_L the thigh.
    "advanced_skeleton": {
        "label": "Advanced Skeleton",
        "prefixes": (),
        "roles": {
            "Hips": ("Root_M",), "Head": ("Head_M",),
            "Shoulder": ("Scapula_{L}",), "UpperArm": ("Shoulder_{L}",), "LowerArm": ("Elbow_{L}",),
            "Hand": ("Wrist_{L}",), "UpperLeg": ("Hip_{L}",), "LowerLeg": ("Knee_{L}",),
            "Foot": ("Ankle_{L}",), "Toes": ("Toes_{L}",),
        },
        "torso": ("Spine{n}_M", "Chest_M", "Neck_M", "Neck{n}_M", "NeckPart{n}_M"),
        "extras": ("HeadEnd_M", "Jaw_M", "JawEnd_M", "Eye_{L}", "EyeEnd_{L}", "ToesEnd_{L}", "*Part{n}_{L}",
                   "*Finger{n}_{L}", "Cup_{L}"),
    },
    # LaFAN1 (Ubisoft La Forge's in-betweening capture): Mixamo's names, toes LeftToe.
    "lafan1": {
        "label": "LaFAN1",
        "prefixes": (),
        "roles": {
            "Hips": ("Hips",), "Head": ("Head",),
            "Shoulder": ("{Left}Shoulder",), "UpperArm": ("{Left}Arm",), "LowerArm": ("{Left}ForeArm",),
            "Hand": ("{Left}Hand",), "UpperLeg": ("{Left}UpLeg",), "LowerLeg": ("{Left}Leg",),
            "Foot": ("{Left}Foot",), "Toes": ("{Left}Toe",),
        },
        "torso": ("Spine", "Spine{n}", "Neck"),
        "extras": (),
    },
    # MakeHuman's default skeleton (MakeHuman 1.x, Blender's MPFB): two segments per limb bone
    # (upperleg01.L, upperleg02.L), toes per digit (toe1-1.L the big toe's). Its pelvis is
    # "root", too common a name to take (many rigs have a root above the hips): the hips come
    # from the topology (the joint the legs and the spine branch from).
    "makehuman": {
        "label": "MakeHuman",
        "prefixes": (),
        "roles": {
            "Head": ("head",),
            "Shoulder": ("clavicle.{L}",), "UpperArm": ("upperarm01.{L}",), "LowerArm": ("lowerarm01.{L}",),
            "Hand": ("wrist.{L}",), "UpperLeg": ("upperleg01.{L}",), "LowerLeg": ("lowerleg01.{L}",),
            "Foot": ("foot.{L}",), "Toes": ("toe1-1.{L}",),
        },
        "torso": ("root", "spine0{n}", "neck0{n}"),
        "extras": ("pelvis.{L}", "shoulder01.{L}", "upperarm02.{L}", "lowerarm02.{L}", "upperleg02.{L}",
                   "lowerleg02.{L}", "toe{n}-{n}.{L}", "metacarpal{n}.{L}", "finger{n}-{n}.{L}", "jaw",
                   "eye.{L}", "levator*", "orbicularis*", "oculi*", "tongue*", "breast.{L}"),
    },
}  # fmt: skip
