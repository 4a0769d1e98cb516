"""The rig bench: one motion on rigs that differ only in their conventions.

From an eval clip on the model skeleton, variant rigs are built whose world motion is the
same: joints renamed to each naming convention, every joint frame turned by a random
constant rotation (rest, bind and animation compensated), another rest pose (the BVH zero
pose, an A-pose, a frame of the animation), Z up, metres, extra joints (twist, zero-length,
fingers). Each is written as a blocked UsdSkel shot (keys every N frames) through usd-core,
filled through the product's fill API, and scored in world joint positions of the model's
joints against the clip. A rig-independent fill scores the same on every variant.
"""

from __future__ import annotations

import errno
import json
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.adapt.hierarchy import ancestors
from pipeline.adapt.mapping import MODEL_JOINTS
from pipeline.bench.outputs import write_outputs
from pipeline.data.split import list_clips, shared_data_dir
from pipeline.fill.api import FillOptions, fill_shot
from pipeline.motion.clip import Motion
from pipeline.motion.rotations import quat_apply, quat_inv, quat_mul

# Model joint → rig joint name, per convention (side written as {s}: L/R, or a word below).
_LR = {"L": ("L", "l", "Left", "left"), "R": ("R", "r", "Right", "right")}
NAMES: dict[str, dict[str, str]] = {
    "mixamo": {"Hips": "mixamorig_Hips", "Spine": "mixamorig_Spine", "Chest": "mixamorig_Spine1",
               "Neck": "mixamorig_Neck", "Head": "mixamorig_Head", "Shoulder": "mixamorig_{W}Shoulder",
               "UpperArm": "mixamorig_{W}Arm", "LowerArm": "mixamorig_{W}ForeArm", "Hand": "mixamorig_{W}Hand",
               "UpperLeg": "mixamorig_{W}UpLeg", "LowerLeg": "mixamorig_{W}Leg", "Foot": "mixamorig_{W}Foot",
               "Toes": "mixamorig_{W}ToeBase"},
    "ue5": {"Hips": "pelvis", "Spine": "spine_01", "Chest": "spine_03", "Neck": "neck_01", "Head": "head",
            "Shoulder": "clavicle_{l}", "UpperArm": "upperarm_{l}", "LowerArm": "lowerarm_{l}",
            "Hand": "hand_{l}", "UpperLeg": "thigh_{l}", "LowerLeg": "calf_{l}", "Foot": "foot_{l}",
            "Toes": "ball_{l}"},
    "character_creator": {"Hips": "CC_Base_Hip", "Spine": "CC_Base_Waist", "Chest": "CC_Base_Spine02",
                          "Neck": "CC_Base_NeckTwist01", "Head": "CC_Base_Head",
                          "Shoulder": "CC_Base_{L}_Clavicle", "UpperArm": "CC_Base_{L}_Upperarm",
                          "LowerArm": "CC_Base_{L}_Forearm", "Hand": "CC_Base_{L}_Hand",
                          "UpperLeg": "CC_Base_{L}_Thigh", "LowerLeg": "CC_Base_{L}_Calf",
                          "Foot": "CC_Base_{L}_Foot", "Toes": "CC_Base_{L}_ToeBase"},
    "rigify": {"Hips": "spine", "Spine": "spine_001", "Chest": "spine_003", "Neck": "spine_004",
               "Head": "spine_006", "Shoulder": "shoulder_{L}", "UpperArm": "upper_arm_{L}",
               "LowerArm": "forearm_{L}", "Hand": "hand_{L}", "UpperLeg": "thigh_{L}", "LowerLeg": "shin_{L}",
               "Foot": "foot_{L}", "Toes": "toe_{L}"},
    "daz": {"Hips": "hip", "Spine": "abdomen", "Chest": "chest", "Neck": "neck", "Head": "head",
            "Shoulder": "{l}Collar", "UpperArm": "{l}Shldr", "LowerArm": "{l}ForeArm", "Hand": "{l}Hand",
            "UpperLeg": "{l}Thigh", "LowerLeg": "{l}Shin", "Foot": "{l}Foot", "Toes": "{l}Toe"},
    "humanik": {"Hips": "Hips", "Spine": "Spine", "Chest": "Spine1", "Neck": "Neck", "Head": "Head",
                "Shoulder": "{W}Shoulder", "UpperArm": "{W}Arm", "LowerArm": "{W}ForeArm", "Hand": "{W}Hand",
                "UpperLeg": "{W}UpLeg", "LowerLeg": "{W}Leg", "Foot": "{W}Foot", "Toes": "{W}ToeBase"},
    "cmu": {"Hips": "Hips", "Spine": "LowerBack", "Chest": "Spine1", "Neck": "Neck", "Head": "Head",
            "Shoulder": "{W}Shoulder", "UpperArm": "{W}Arm", "LowerArm": "{W}ForeArm", "Hand": "{W}Hand",
            "UpperLeg": "{W}UpLeg", "LowerLeg": "{W}Leg", "Foot": "{W}Foot", "Toes": "{W}ToeBase"},
    "unity": {"Hips": "Hips", "Spine": "Spine", "Chest": "UpperChest", "Neck": "Neck", "Head": "Head",
              "Shoulder": "{W}Shoulder", "UpperArm": "{W}UpperArm", "LowerArm": "{W}LowerArm", "Hand": "{W}Hand",
              "UpperLeg": "{W}UpperLeg", "LowerLeg": "{W}LowerLeg", "Foot": "{W}Foot", "Toes": "{W}Toes"},
    "vrm": {"Hips": "J_Bip_C_Hips", "Spine": "J_Bip_C_Spine", "Chest": "J_Bip_C_Chest", "Neck": "J_Bip_C_Neck",
            "Head": "J_Bip_C_Head", "Shoulder": "J_Bip_{L}_Shoulder", "UpperArm": "J_Bip_{L}_UpperArm",
            "LowerArm": "J_Bip_{L}_LowerArm", "Hand": "J_Bip_{L}_Hand", "UpperLeg": "J_Bip_{L}_UpperLeg",
            "LowerLeg": "J_Bip_{L}_LowerLeg", "Foot": "J_Bip_{L}_Foot", "Toes": "J_Bip_{L}_ToeBase"},
    "xsens": {"Hips": "Pelvis", "Spine": "L5", "Chest": "T8", "Neck": "Neck", "Head": "Head",
              "Shoulder": "{W}Shoulder", "UpperArm": "{W}UpperArm", "LowerArm": "{W}ForeArm", "Hand": "{W}Hand",
              "UpperLeg": "{W}UpperLeg", "LowerLeg": "{W}LowerLeg", "Foot": "{W}Foot", "Toes": "{W}Toe"},
    "optitrack": {"Hips": "Skeleton1_Hip", "Spine": "Skeleton1_Ab", "Chest": "Skeleton1_Chest",
                  "Neck": "Skeleton1_Neck", "Head": "Skeleton1_Head", "Shoulder": "Skeleton1_{L}Shoulder",
                  "UpperArm": "Skeleton1_{L}UArm", "LowerArm": "Skeleton1_{L}FArm", "Hand": "Skeleton1_{L}Hand",
                  "UpperLeg": "Skeleton1_{L}Thigh", "LowerLeg": "Skeleton1_{L}Shin", "Foot": "Skeleton1_{L}Foot",
                  "Toes": "Skeleton1_{L}Toe"},
    "smpl": {"Hips": "pelvis", "Spine": "spine1", "Chest": "spine3", "Neck": "neck", "Head": "head",
             "Shoulder": "{w}_collar", "UpperArm": "{w}_shoulder", "LowerArm": "{w}_elbow", "Hand": "{w}_wrist",
             "UpperLeg": "{w}_hip", "LowerLeg": "{w}_knee", "Foot": "{w}_ankle", "Toes": "{w}_foot"},
    "advanced_skeleton": {"Hips": "Root_M", "Spine": "Spine1_M", "Chest": "Chest_M", "Neck": "Neck_M",
                          "Head": "Head_M", "Shoulder": "Scapula_{L}", "UpperArm": "Shoulder_{L}",
                          "LowerArm": "Elbow_{L}", "Hand": "Wrist_{L}", "UpperLeg": "Hip_{L}",
                          "LowerLeg": "Knee_{L}", "Foot": "Ankle_{L}", "Toes": "Toes_{L}"},
    # A studio's own naming, no convention's (pipeline.adapt.chains places its limbs).
    "studio": {"Hips": "C_pelvis_jnt", "Spine": "C_spine1_jnt", "Chest": "C_chest_jnt", "Neck": "C_neck_jnt",
               "Head": "C_head_jnt", "Shoulder": "{L}_clav_jnt", "UpperArm": "{L}_shoulder_jnt",
               "LowerArm": "{L}_elbow_jnt", "Hand": "{L}_wrist_jnt", "UpperLeg": "{L}_thigh_jnt",
               "LowerLeg": "{L}_knee_jnt", "Foot": "{L}_ankle_jnt", "Toes": "{L}_ball_jnt"},
}  # fmt: skip
#: Every variant of the bench, in table order.
VARIANTS = (
    *(f"names:{c}" for c in NAMES),
    "frames",
    "rest:zero",
    "rest:a-pose",
    "rest:frame",
    "z-up",
    "metres",
    "extra:twist",
    "extra:zero-length",
    "extra:fingers",
    "all:ue5+frames+z-up+metres+twist",
    "all:rest:zero+frames+z-up+metres",  # what Blender's BVH import then USD export writes
)


@dataclass
class Rig:
    """A rig as arrays: names, parents, rest locals; animation locals at every frame."""

    names: list[str]
    parents: np.ndarray
    rest_rot: np.ndarray  # (J, 4)
    rest_trans: np.ndarray  # (J, 3)
    rot: np.ndarray  # (T, J, 4)
    trans: np.ndarray  # (T, J, 3)
    up_axis: str = "Y"
    mpu: float = 0.01
    model_index: dict[str, int] | None = None  # model joint → rig joint (for scoring)


def model_rig_of(motion: Motion) -> Rig:
    """The clip on the model skeleton, rest pose as ``tween convert`` writes it."""
    from pipeline.usd.convert import rest_pose

    sk = motion.skeleton
    rest_rot, rest_trans = rest_pose(motion)
    T = len(motion)
    trans = np.broadcast_to(sk.offsets.astype(np.float64), (T, len(sk), 3)).copy()
    trans[:, 0] = motion.root_positions
    return Rig(list(sk.names), sk.parents.copy(), rest_rot, rest_trans, motion.rotations.astype(np.float64),
               trans, model_index={n: i for i, n in enumerate(sk.names)})  # fmt: skip


def _side_name(pattern: str, side: str) -> str:
    s, lo, word, wlo = _LR[side]
    return pattern.replace("{L}", s).replace("{l}", lo).replace("{W}", word).replace("{w}", wlo)


def renamed(rig: Rig, convention: str) -> Rig:
    table = NAMES[convention]
    names = []
    for n in rig.names:
        role, _, side = n.partition("_")
        names.append(_side_name(table[role], side) if side else table[role])
    return Rig(names, rig.parents, rig.rest_rot, rig.rest_trans, rig.rot, rig.trans, rig.up_axis, rig.mpu,
               dict(rig.model_index))  # fmt: skip


def _conj(q: np.ndarray, C: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """Locals of the same world pose on joint frames turned by C: C_parent⁻¹ · q · C."""
    Cp = np.stack([C[p] if p >= 0 else [0.0, 0, 0, 1] for p in parents])
    return quat_mul(quat_mul(np.broadcast_to(quat_inv(Cp), q.shape), q), np.broadcast_to(C, q.shape))


def reframed(rig: Rig, seed: int = 0, max_deg: float = 60.0) -> Rig:
    """Every joint frame turned by a random constant rotation of at most ``max_deg``."""
    rng = np.random.default_rng(seed)
    J = len(rig.names)
    axis = rng.normal(size=(J, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    C = Rotation.from_rotvec(axis * np.radians(rng.uniform(20, max_deg, J))[:, None]).as_quat()
    Cp = np.stack([C[p] if p >= 0 else [0.0, 0, 0, 1] for p in rig.parents])
    return Rig(rig.names, rig.parents, _conj(rig.rest_rot, C, rig.parents),
               quat_apply(quat_inv(Cp), rig.rest_trans), _conj(rig.rot, C, rig.parents),
               quat_apply(np.broadcast_to(quat_inv(Cp), rig.trans.shape[:2] + (4,)), rig.trans),
               rig.up_axis, rig.mpu, dict(rig.model_index))  # fmt: skip


def _globals(rot: np.ndarray, parents: np.ndarray) -> np.ndarray:
    g = np.empty_like(rot)
    for j, p in enumerate(parents):
        g[..., j, :] = rot[..., j, :] if p < 0 else quat_mul(g[..., p, :], rot[..., j, :])
    return g


def _locals(g: np.ndarray, parents: np.ndarray) -> np.ndarray:
    return np.stack([g[j] if p < 0 else quat_mul(quat_inv(g[p]), g[j]) for j, p in enumerate(parents)])


def rest_replaced(rig: Rig, kind: str, frame: int = 7) -> Rig:
    """Another rest pose: ``zero`` (every rest rotation identity, as a BVH importer writes),
    ``a-pose`` (the T-pose with the upper arms lowered 45 degrees), ``frame`` (a frame of
    the animation)."""
    rest_rot, rest_trans = rig.rest_rot.copy(), rig.rest_trans.copy()
    if kind == "zero":
        rest_rot[:] = (0, 0, 0, 1)
    elif kind == "a-pose":
        g = _globals(rest_rot, rig.parents)
        for side, sign in (("L", -1), ("R", 1)):
            j = rig.model_index[f"UpperArm_{side}"]
            g_sub = [j] + [i for i in range(len(rig.parents)) if j in ancestors(rig.parents, i)[1:]]
            turn = Rotation.from_rotvec([0, 0, sign * np.pi / 4]).as_quat()
            g[g_sub] = quat_mul(np.broadcast_to(turn, (len(g_sub), 4)), g[g_sub])
        rest_rot = _locals(g, rig.parents)
    elif kind == "frame":
        rest_rot, rest_trans = rig.rot[frame].copy(), rig.trans[frame].copy()
    else:
        raise ValueError(kind)
    return Rig(rig.names, rig.parents, rest_rot, rest_trans, rig.rot, rig.trans, rig.up_axis, rig.mpu,
               dict(rig.model_index))  # fmt: skip


_Y_TO_Z = Rotation.from_euler("x", 90, degrees=True)


def z_up(rig: Rig) -> Rig:
    """The same motion in a Z-up skeleton space (the root joint turned, as a Z-up DCC writes)."""
    q = np.broadcast_to(_Y_TO_Z.as_quat(), (4,))
    rest_rot, rest_trans = rig.rest_rot.copy(), rig.rest_trans.copy()
    rot, trans = rig.rot.copy(), rig.trans.copy()
    for r, t in ((rest_rot, rest_trans), (rot, trans)):
        r[..., 0, :] = quat_mul(np.broadcast_to(q, r[..., 0, :].shape), r[..., 0, :])
        t[..., 0, :] = _Y_TO_Z.apply(t[..., 0, :].reshape(-1, 3)).reshape(t[..., 0, :].shape)
    return Rig(rig.names, rig.parents, rest_rot, rest_trans, rot, trans, "Z", rig.mpu, dict(rig.model_index))


def metres(rig: Rig) -> Rig:
    """metersPerUnit 1: every translation in metres."""
    f = rig.mpu
    return Rig(rig.names, rig.parents, rig.rest_rot, rig.rest_trans * f, rig.rot, rig.trans * f, rig.up_axis,
               1.0, dict(rig.model_index))  # fmt: skip


def with_extra(rig: Rig, kind: str) -> Rig:
    """Extra joints: ``twist`` (a twist joint inside each upper arm and leg, halving the bone,
    and a twisting leaf under each forearm), ``zero-length`` (a joint of zero length between
    the hips and each thigh, as on the CMU rig), ``fingers`` (five 3-joint fingers a hand)."""
    T = rig.rot.shape[0]
    names, parents = list(rig.names), list(rig.parents)
    rest_rot, rest_trans = list(rig.rest_rot), list(rig.rest_trans)
    rot, trans = list(np.moveaxis(rig.rot, 1, 0)), list(np.moveaxis(rig.trans, 1, 0))
    ident = np.array([0.0, 0, 0, 1])

    def add(name, parent, offset, anim_rot=None):
        names.append(name)
        parents.append(parent)
        rest_rot.append(ident.copy())
        rest_trans.append(np.asarray(offset, np.float64))
        rot.append(np.tile(ident, (T, 1)) if anim_rot is None else anim_rot)
        trans.append(np.tile(np.asarray(offset, np.float64), (T, 1)))
        return len(names) - 1

    idx = rig.model_index
    for s in "LR":
        if kind == "twist":
            for upper, lower in (("UpperArm", "LowerArm"), ("UpperLeg", "LowerLeg")):
                lo = idx[f"{lower}_{s}"]
                half = rest_trans[lo] / 2
                tw = add(f"{upper}Twist_{s}", idx[f"{upper}_{s}"], half)
                parents[lo] = tw
                rest_trans[lo] = rest_trans[lo] - half
                trans[lo] = trans[lo] - half
            hand = rest_trans[idx[f"Hand_{s}"]]
            spin = Rotation.from_rotvec(
                np.outer(np.sin(np.arange(T) / 9), hand / np.linalg.norm(hand))
            ).as_quat()
            add(f"ForeArmTwist_{s}", idx[f"LowerArm_{s}"], hand / 2, spin)
        elif kind == "zero-length":
            up = idx[f"UpperLeg_{s}"]
            z = add(f"HipJoint_{s}", parents[up], np.zeros(3))
            parents[up] = z
        elif kind == "fingers":
            for f, name in enumerate(("Thumb", "Index", "Middle", "Ring", "Pinky")):
                p = add(f"{name}1_{s}", idx[f"Hand_{s}"], (4.0, 0.0, (f - 2) * 1.5))
                for k in (2, 3):
                    p = add(f"{name}{k}_{s}", p, (2.5, 0.0, 0.0))
        else:
            raise ValueError(kind)
    # Parents must come first: order the joints depth-first from the root.
    order: list[int] = []

    def visit(j):
        order.append(j)
        for c in [i for i, p in enumerate(parents) if p == j]:
            visit(c)

    for r in [i for i, p in enumerate(parents) if p < 0]:
        visit(r)
    new = {old: k for k, old in enumerate(order)}
    return Rig([names[o] for o in order], np.array([new[parents[o]] if parents[o] >= 0 else -1 for o in order]),
               np.array([rest_rot[o] for o in order]), np.array([rest_trans[o] for o in order]),
               np.stack([rot[o] for o in order], 1), np.stack([trans[o] for o in order], 1), rig.up_axis,
               rig.mpu, {m: new[i] for m, i in idx.items()})  # fmt: skip


def variant(rig: Rig, name: str, seed: int = 0) -> Rig:
    """The variant ``name`` (one of VARIANTS) of the model-skeleton ``rig``."""
    out = rig
    for part in name.split(":", 1)[1].split("+") if name.startswith("all:") else [name]:
        if part.startswith("names:") or part in NAMES:
            out = renamed(out, part.split(":")[-1])
        elif part == "frames":
            out = reframed(out, seed)
        elif part.startswith("rest:"):
            out = rest_replaced(out, part[5:])
        elif part == "z-up":
            out = z_up(out)
        elif part == "metres":
            out = metres(out)
        elif part.startswith("extra:") or part in ("twist", "zero-length", "fingers"):
            out = with_extra(out, part.split(":")[-1])
        else:
            raise ValueError(f"unknown rig variant {part!r}")
    return out


def write_rig_shot(rig: Rig, path: str | Path, keys_every: int = 10, start: float = 1001) -> Path:
    """A blocked UsdSkel shot of ``rig``: samples at every ``keys_every``-th frame and the last."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt

    path = Path(path)
    T = rig.rot.shape[0]
    keys = sorted(set(range(0, T, keys_every)) | {T - 1})
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z if rig.up_axis == "Z" else UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, rig.mpu)
    stage.SetTimeCodesPerSecond(30)
    stage.SetFramesPerSecond(30)
    stage.SetStartTimeCode(start)
    stage.SetEndTimeCode(start + T - 1)
    UsdGeom.Xform.Define(stage, "/World")
    root = UsdSkel.Root.Define(stage, "/World/Character")
    skel = UsdSkel.Skeleton.Define(stage, "/World/Character/Skel")
    tokens = []
    for j, p in enumerate(rig.parents):
        tokens.append(rig.names[j] if p < 0 else f"{tokens[p]}/{rig.names[j]}")
    assert all(Sdf.Path.IsValidPathString(t) for t in tokens)

    def mats(rot, trans):
        return Vt.Matrix4dArray(
            [
                Gf.Matrix4d(Gf.Rotation(Gf.Quatd(float(q[3]), *map(float, q[:3]))), Gf.Vec3d(*map(float, t)))
                for q, t in zip(rot, trans, strict=True)
            ]  # fmt: skip
        )

    g = _globals(rig.rest_rot, rig.parents)
    gp = np.zeros_like(rig.rest_trans)
    for j, p in enumerate(rig.parents):
        gp[j] = rig.rest_trans[j] if p < 0 else gp[p] + quat_apply(g[p], rig.rest_trans[j])
    skel.CreateJointsAttr(Vt.TokenArray(tokens))
    skel.CreateRestTransformsAttr(mats(rig.rest_rot, rig.rest_trans))
    skel.CreateBindTransformsAttr(mats(g, gp))
    anim = UsdSkel.Animation.Define(stage, "/World/Character/Skel/Anim")
    anim.CreateJointsAttr(Vt.TokenArray(tokens))
    ra, ta, sa = anim.CreateRotationsAttr(), anim.CreateTranslationsAttr(), anim.CreateScalesAttr()
    for k in keys:
        t = Usd.TimeCode(start + k)
        ra.Set(Vt.QuatfArray([Gf.Quatf(float(q[3]), *map(float, q[:3])) for q in rig.rot[k]]), t)
        ta.Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, v)) for v in rig.trans[k]]), t)
        sa.Set(Vt.Vec3hArray([Gf.Vec3h(1, 1, 1)] * len(tokens)), t)
    binding = UsdSkel.BindingAPI.Apply(skel.GetPrim())
    binding.CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    UsdSkel.BindingAPI.Apply(root.GetPrim()).CreateSkeletonRel().SetTargets([skel.GetPath()])
    stage.GetRootLayer().Save()
    return path


def network_input(shot: str | Path) -> tuple[np.ndarray, np.ndarray, str]:
    """What the human model receives for the shot's one character at its keys: model-ordered
    local rotations (K, 21, 4), root positions (K, 3) in the canonical frame, and the
    reference the retargeter chose."""
    from pipeline.fill.plan import make_plan
    from pipeline.usd.read import anim_values, to_skeleton_order

    plan = make_plan(str(shot), None, None, None, 30.0)
    cp = plan.chars[0]
    rot, tr, _ = anim_values(plan.shot.stage, cp.char, cp.keys)
    local, root = cp.retarget.to_model(*to_skeleton_order(cp.char, rot, tr))
    return local, root, cp.retarget.reference


def filled_positions(review: str, rig: Rig) -> np.ndarray:
    """World positions in metres, Y up (T, 21, 3), of the model's joints on ``rig`` in the
    fill's review stage."""
    from pxr import Usd, UsdGeom, UsdSkel

    stage = Usd.Stage.Open(review)
    cache = UsdSkel.Cache()
    root = UsdSkel.Root(stage.GetPrimAtPath("/World/Character"))
    cache.Populate(root, Usd.PrimDefaultPredicate)
    q = cache.GetSkelQuery(UsdSkel.Skeleton(stage.GetPrimAtPath("/World/Character/Skel")))
    order = [rig.model_index[m] for m in MODEL_JOINTS]
    T = rig.rot.shape[0]
    start = stage.GetStartTimeCode()
    out = np.empty((T, len(order), 3))
    for i in range(T):
        m = np.array(q.ComputeJointSkelTransforms(Usd.TimeCode(start + i)))
        out[i] = m[order, 3, :3]
    out *= UsdGeom.GetStageMetersPerUnit(stage)
    if rig.up_axis == "Z":
        out = _Y_TO_Z.inv().apply(out.reshape(-1, 3)).reshape(out.shape)
    return out


def fill_review(shot: Path, model: str, out: Path) -> str:
    """The bench's fill of a shot: the product's own (``tween fill-local SHOT --model MODEL
    --out-dir OUT``, bit for bit); returns the review stage's path."""
    return fill_shot(str(shot), FillOptions(model=model, out_dir=str(out)))["review"]


def run_rig_bench(
    clips: list[Motion],
    variants: tuple[str, ...] = VARIANTS,
    methods: tuple[str, ...] = ("model", "interp", "spline"),
    keys_every: int = 10,
    out: Path | None = None,
) -> dict:
    """Mean world joint error (cm, non-key frames) of each method on each variant, summed
    over ``clips``, and each method's ratio variant / model-skeleton rig."""
    err: dict[str, dict[str, list[float]]] = {
        v: {m: [] for m in methods} for v in ("model skeleton", *variants)
    }
    net: dict[str, float] = {}
    refs: dict[str, str] = {}
    with tempfile.TemporaryDirectory(prefix="tween-rigbench-") as tmp:
        for ci, clip in enumerate(clips):
            base = model_rig_of(clip)
            truth = clip.positions() * clip.skeleton.meters_per_unit
            T = len(clip)
            inside = np.setdiff1d(np.arange(T), np.r_[np.arange(0, T, keys_every), T - 1])
            base_in = None
            for v in ("model skeleton", *variants):
                rig = base if v == "model skeleton" else variant(base, v, seed=ci)
                d = Path(tmp) / f"c{ci}_{v.replace(':', '_').replace('+', '_')}"
                d.mkdir()
                shot = write_rig_shot(rig, d / "shot.usda", keys_every)
                local, root, ref = network_input(shot)
                refs[v] = ref
                if base_in is None:
                    base_in = (local, root)
                else:
                    dq = np.abs(np.abs((local.astype(np.float64) * base_in[0]).sum(-1)) - 1).max()
                    dr = np.abs(root - base_in[1]).max() / 100.0  # cm → m... as a fraction of a metre
                    net[v] = max(net.get(v, 0.0), float(dq), float(dr))
                for m in methods:
                    pos = filled_positions(fill_review(shot, "default" if m == "model" else m, d / m), rig)
                    e = np.linalg.norm(pos[inside] - truth[inside], axis=-1).mean() * 100
                    err[v][m].append(float(e))
                print(f"tween: rig bench clip {ci + 1}/{len(clips)} {v}: done", file=sys.stderr)
    table = {v: {m: float(np.mean(x)) for m, x in d.items()} for v, d in err.items()}
    base = table["model skeleton"]
    res = {
        "keys_every": keys_every,
        "clips": [c.name for c in clips],
        "error_cm": table,
        "ratio_to_model_skeleton": {v: {m: t[m] / base[m] for m in methods} for v, t in table.items()},
        "network_input_max_diff": net,
        "reference": refs,
    }
    res["markdown"] = _markdown(res, methods)
    if out is not None:
        text = json.dumps({k: v for k, v in res.items() if k != "markdown"}, indent=1)
        write_outputs(out, {"rig_bench.json": text, "rig_bench.md": res["markdown"]})
    return res


def _markdown(res: dict, methods) -> str:
    head = (
        "| rig | reference | input diff | " + " | ".join(f"{m} cm | {m} ÷ model rig" for m in methods) + " |"
    )
    lines = [head, "|" + "---|" * (3 + 2 * len(methods))]
    for v, t in res["error_cm"].items():
        r = res["ratio_to_model_skeleton"][v]
        d = res["network_input_max_diff"].get(v)
        cells = " | ".join(f"{t[m]:.3f} | {r[m]:.4f}" for m in methods)
        lines.append(f"| {v} | {res['reference'][v]} | {'' if d is None else f'{d:.1e}'} | {cells} |")
    return "\n".join(lines) + "\n"


def bench_clips(n: int = 8, frames: int = 241) -> list[Motion]:
    """``n`` eval clips spread evenly over the split's sorted file list (so several actions
    and styles), each cut to its first ``frames`` frames."""
    from pipeline.motion.bvh import read_bvh

    files = list_clips("eval")
    if not files:
        raise FileNotFoundError(errno.ENOENT, "no eval clips there", str(shared_data_dir()))
    pick = [files[int(i)] for i in np.linspace(0, len(files) - 1, min(n, len(files)))]
    return [read_bvh(f).slice(0, frames) for f in pick]
