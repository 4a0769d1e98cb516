"""A shot as Blender 5's USD exporter writes it, authored with the UsdSkel API (no USD text).

The traits the review has to cope with:

- joint tokens are full paths (``root/Hips/Spine``), ``upAxis = "Z"``, ``metersPerUnit = 1``;
- ``timeCodesPerSecond = 30.0000304`` and no ``framesPerSecond`` (``GetFramesPerSecond()``
  then answers USD's fallback, 24);
- a sample on every frame, time codes 1..N (integers), start/end time codes authored;
- the rest pose is the BVH zero pose: every rest rotation is identity and every offset points
  along +X (so the rest pose is a straight line, not a human shape);
- a static root bone ``root`` with ``Hips`` under it carrying the motion: the hips walk a
  curved path of several metres (starting away from the origin, as a mocap clip does) while
  ``root`` stays at the origin.

No mesh is bound, so the renderer draws its capsule mannequin.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pxr import Gf, Usd, UsdGeom, UsdSkel, Vt

TCPS = 30.0000304
FRAMES = 261

# (name, parent index, offset along +X in metres)
JOINTS = [
    ("root", -1, 0.0),
    ("Hips", 0, 0.95),
    ("Spine", 1, 0.12),
    ("Chest", 2, 0.16),
    ("Neck", 3, 0.24),
    ("Head", 4, 0.10),
    ("Shoulder_L", 3, 0.20),
    ("UpperArm_L", 6, 0.16),
    ("LowerArm_L", 7, 0.28),
    ("Shoulder_R", 3, 0.20),
    ("UpperArm_R", 9, 0.16),
    ("LowerArm_R", 10, 0.28),
    ("UpperLeg_L", 1, 0.08),
    ("LowerLeg_L", 12, 0.45),
    ("Foot_L", 13, 0.43),
    ("UpperLeg_R", 1, 0.08),
    ("LowerLeg_R", 15, 0.45),
    ("Foot_R", 16, 0.43),
]


def joint_paths(names: list[str] | None = None) -> list[str]:
    names = names or [n for n, _, _ in JOINTS]
    paths: list[str] = []
    for (_, p, _), name in zip(JOINTS, names, strict=True):
        paths.append(name if p < 0 else f"{paths[p]}/{name}")
    return paths


def _q(axis, deg: float) -> Gf.Quatf:
    return Gf.Quatf(Gf.Rotation(Gf.Vec3d(*axis), float(deg)).GetQuat())


def hips_path(frames: int = FRAMES) -> np.ndarray:
    """(frames, 3) hips positions, Z up, metres: 4 m along X on a 1.5 m arc in Y, a small bob."""
    s = np.linspace(0.0, 1.0, frames)
    return np.stack(
        [1.5 + 4.0 * s, 1.5 * np.sin(np.pi * s), 0.95 + 0.03 * np.sin(2 * np.pi * s * frames / 30)], 1
    )


def build_blender_shot(
    out: Path,
    frames: int = FRAMES,
    names: list[str] | None = None,
    time_range: bool = True,
) -> dict:
    """Writes the shot to ``out``; returns {"path", "times" (the time codes), "hips" (positions)}.

    ``names`` renames the joints (same hierarchy); ``time_range=False`` leaves the start/end
    time codes unauthored (the range is then the animation's samples).
    """
    stage = Usd.Stage.CreateNew(str(out))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(TCPS)  # and no framesPerSecond, as Blender writes it
    if time_range:
        stage.SetStartTimeCode(1)
        stage.SetEndTimeCode(frames)
    top = UsdGeom.Xform.Define(stage, "/root")
    stage.SetDefaultPrim(top.GetPrim())
    UsdSkel.Root.Define(stage, "/root/Armature")
    skel = UsdSkel.Skeleton.Define(stage, "/root/Armature/Armature")
    paths = joint_paths(names)
    offsets = [Gf.Vec3f(x, 0.0, 0.0) for _, _, x in JOINTS]
    rest = Vt.Matrix4dArray([Gf.Matrix4d(1.0).SetTranslate(Gf.Vec3d(o)) for o in offsets])
    skel.CreateJointsAttr(paths)
    skel.CreateRestTransformsAttr(rest)
    skel.CreateBindTransformsAttr(UsdSkel.ConcatJointTransforms(UsdSkel.Topology(paths), rest))
    anim = UsdSkel.Animation.Define(stage, "/root/Armature/Armature/Anim")
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    anim.CreateJointsAttr(paths)
    anim.CreateScalesAttr(Vt.Vec3hArray([Gf.Vec3h(1, 1, 1)] * len(JOINTS)))
    rot_attr, tr_attr = anim.CreateRotationsAttr(), anim.CreateTranslationsAttr()

    hips = hips_path(frames)
    heading = np.degrees(np.arctan2(np.gradient(hips[:, 1]), np.gradient(hips[:, 0])))
    times = np.arange(1, frames + 1, dtype=np.float64)
    ident = Gf.Quatf(1.0)
    for i, t in enumerate(times):
        swing = 25.0 * np.sin(2 * np.pi * i / 30)
        # Hips: local +X (every offset's direction) turned to point up (+Z), facing along the path.
        hip_rot = _q((0, 0, 1), heading[i]) * _q((0, 1, 0), -90.0)
        rots = [ident, hip_rot, ident, ident, ident, ident]
        for side in (1, -1):  # shoulders out sideways, arms hanging and swinging
            rots += [_q((0, 0, 1), 90.0 * side), _q((0, 0, 1), 80.0 * side) * _q((1, 0, 0), swing), ident]
        for side in (1, -1):  # legs down, slightly apart, swinging in turn
            rots += [_q((0, 1, 0), swing * side) * _q((0, 0, 1), 180.0 + 8.0 * side), ident, ident]
        trans = list(offsets)
        trans[1] = Gf.Vec3f(*map(float, hips[i]))
        rot_attr.Set(Vt.QuatfArray(rots), Usd.TimeCode(float(t)))
        tr_attr.Set(Vt.Vec3fArray(trans), Usd.TimeCode(float(t)))
    stage.GetRootLayer().Save()
    return {"path": str(out), "times": times, "hips": hips}
