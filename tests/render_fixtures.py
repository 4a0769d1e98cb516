"""Review stages from a real Bandai clip.

``converted_review`` uses the project's own path (``pipeline.usd.convert.write_shot`` then
``pipeline.fill.fill_shot`` with the interpolation model). ``build_shot`` authors a stage
directly with UsdSkel APIs (no skinned mesh, so the renderer's capsule mannequin is used).

The shot is on the shot's own frame numbers (1001...), centimetres, Y up, 30 fps, like a
studio shot; the fill's facts are authored as ``tween:*`` attributes on the SkelAnimation, and
takes live in a ``tweenTake`` variant set on the SkelRoot.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt

from pipeline.motion.bvh import read_bvh
from pipeline.motion.clip import Motion

START = 1001


def _joint_paths(motion: Motion) -> list[str]:
    sk = motion.skeleton
    paths: list[str] = []
    for j, name in enumerate(sk.names):
        p = sk.parents[j]
        paths.append(name if p < 0 else f"{paths[p]}/{name}")
    return paths


def _matrices(rots: np.ndarray, trans: np.ndarray) -> Vt.Matrix4dArray:
    return Vt.Matrix4dArray(
        [
            Gf.Matrix4d(
                Gf.Rotation(Gf.Quatd(float(q[3]), float(q[0]), float(q[1]), float(q[2]))),
                Gf.Vec3d(*map(float, t)),
            )
            for q, t in zip(rots, trans, strict=True)
        ]
    )


def _author_anim(anim: UsdSkel.Animation, motion: Motion, frames, tween_facts: dict | None) -> None:
    sk = motion.skeleton
    anim.CreateJointsAttr(_joint_paths(motion))
    anim.CreateScalesAttr(Vt.Vec3hArray([Gf.Vec3h(1, 1, 1)] * len(sk)))
    rot_attr, tr_attr = anim.CreateRotationsAttr(), anim.CreateTranslationsAttr()
    for i in frames:
        tr = sk.offsets.copy()
        tr[0] = motion.root_positions[i]
        t = Usd.TimeCode(START + int(i))
        rot_attr.Set(Vt.QuatfArray.FromNumpy(np.ascontiguousarray(motion.rotations[i], np.float32)), t)
        tr_attr.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(tr, np.float32)), t)
    if tween_facts:
        prim = anim.GetPrim()
        prim.CreateAttribute("tween:keyTimes", Sdf.ValueTypeNames.DoubleArray).Set(
            Vt.DoubleArray([START + float(k) for k in tween_facts["keys"]])
        )
        for name, typ in (
            ("model", Sdf.ValueTypeNames.String),
            ("modelHash", Sdf.ValueTypeNames.String),
            ("take", Sdf.ValueTypeNames.Int),
            ("seed", Sdf.ValueTypeNames.Int),
        ):
            if name in tween_facts:
                prim.CreateAttribute(f"tween:{name}", typ).Set(tween_facts[name])


def build_shot(
    clip: Path,
    out: Path,
    frames: int = 90,
    key_step: int = 10,
    filled: bool = True,
    takes: int = 0,
    up_axis: str = "Y",
) -> dict:
    """Writes a review stage; returns {"path", "keys" (frame numbers), "frames" (count)}.

    ``filled``: every frame authored plus ``tween:*`` facts (keys every ``key_step``); otherwise
    a plain animator's shot with only the key frames authored. ``takes`` > 0 adds a
    ``tweenTake`` variant set whose take N lifts the character by N*20 cm (so takes differ).
    """
    motion = read_bvh(clip)
    motion = motion.slice(0, min(frames, len(motion)))
    T = len(motion)
    keys = list(range(0, T, key_step))
    if keys[-1] != T - 1:
        keys.append(T - 1)
    stage = Usd.Stage.CreateNew(str(out))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up_axis == "Y" else UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, motion.skeleton.meters_per_unit)
    stage.SetTimeCodesPerSecond(motion.fps)
    stage.SetFramesPerSecond(motion.fps)
    stage.SetStartTimeCode(START)
    stage.SetEndTimeCode(START + T - 1)
    world = UsdGeom.Xform.Define(stage, "/Shot")
    stage.SetDefaultPrim(world.GetPrim())
    if up_axis == "Z":  # a Y-up clip under a Z-up stage: rotate it so it stands on the Z-up ground
        UsdGeom.Xformable(world).AddRotateXOp().Set(90.0)
    root = UsdSkel.Root.Define(stage, "/Shot/Char")
    skel = UsdSkel.Skeleton.Define(stage, "/Shot/Char/Skel")
    sk = motion.skeleton
    ident = np.tile(np.array([0, 0, 0, 1], np.float32), (len(sk), 1))
    rest = _matrices(ident, sk.offsets)
    skel.CreateJointsAttr(_joint_paths(motion))
    skel.CreateRestTransformsAttr(rest)
    skel.CreateBindTransformsAttr(UsdSkel.ConcatJointTransforms(UsdSkel.Topology(_joint_paths(motion)), rest))
    anim = UsdSkel.Animation.Define(stage, "/Shot/Char/Skel/Anim")
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    facts = {"keys": keys, "model": "interp", "modelHash": "0123456789abcdef0123", "seed": 7}
    if takes:
        vset = root.GetPrim().GetVariantSets().AddVariantSet("tweenTake")
        for n in range(takes):
            vset.AddVariant(f"take{n}")
            vset.SetVariantSelection(f"take{n}")
            with vset.GetVariantEditContext():
                lifted = Motion(
                    sk,
                    motion.rotations,
                    motion.root_positions + np.array([0, 20.0 * n, 0], np.float32),
                    motion.fps,
                )
                _author_anim(anim, lifted, range(T), {**facts, "take": n})
        vset.SetVariantSelection("take0")
    else:
        _author_anim(anim, motion, range(T) if filled else keys, {**facts, "take": 0} if filled else None)
    stage.GetRootLayer().Save()
    return {"path": str(out), "keys": [START + k for k in keys], "frames": T}


def start_frames() -> int:
    return START


def converted_review(clip: Path, work: Path, frames: int = 60, key_step: int = 10, takes: int = 2,
                     name: str = "sh010") -> tuple[str, list[int]]:  # fmt: skip
    """Converts ``clip`` to a shot keyed every ``key_step`` frames and fills it with the
    interpolation model; returns (review root layer, key frame numbers)."""
    from pipeline.fill.api import FillOptions, fill_shot
    from pipeline.usd.convert import write_shot

    motion = read_bvh(clip).slice(0, frames)
    shot = write_shot(motion, work / f"{name}.usda", start=START, keys_every=key_step)
    result = fill_shot(shot, FillOptions(takes=takes, model="interp", out_dir=str(work)))
    keys = list(range(0, len(motion), key_step))
    if keys[-1] != len(motion) - 1:
        keys.append(len(motion) - 1)
    return result["review"], [START + k for k in keys]


def long_walk(clip: Path, frames: int = 300) -> Motion:
    """``clip`` carried on past its end to ``frames`` frames: after its last frame the clip
    plays again from just after the pose closest to that last one (the gait's phase), moved
    on the ground so the root carries on. A 7-s walk becomes a 10-s one that walks further."""
    m = read_bvh(clip)
    n = len(m)
    rots, roots = [m.rotations], [m.root_positions]
    while sum(len(r) for r in rots) < frames:
        last_rot, last_root = rots[-1][-1], roots[-1][-1]
        step = roots[-1][-1] - roots[-1][-2]
        similar = np.abs(np.einsum("tjc,jc->tj", m.rotations[: 2 * n // 3], last_rot)).sum(1)
        s = int(np.argmax(similar)) + 1
        off = last_root + step - m.root_positions[s]
        off[1] = 0.0
        rots.append(m.rotations[s:])
        roots.append(m.root_positions[s:] + off)
    return Motion(
        m.skeleton,
        np.concatenate(rots)[:frames],
        np.concatenate(roots)[:frames],
        m.fps,
        f"{m.name} x{frames}",
    )
