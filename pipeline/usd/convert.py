"""BVH → USD shot: SkelRoot with Skeleton, SkelAnimation and a skinned box mannequin.

Authored through usd-core's UsdSkel/UsdGeom APIs. The rest and bind pose is the
canonical T-pose of the rig (when its joints map onto the model skeleton) so the
mannequin is modelled in a sensible pose and any tool can retarget from it.

Joint names that are not USD identifiers (Rigify ``spine.001``, Mixamo ``mixamorig:Hips``,
names with spaces, ``/`` or accents) are made into identifiers by :func:`usd_joint_names`;
the names as written in the BVH are then kept on the Skeleton in ``tween:sourceJointNames``.
"""

from __future__ import annotations

import os
import re
import unicodedata
from pathlib import Path

import numpy as np

import pipeline.usd  # noqa: F401
from pipeline.adapt.mapping import MODEL_JOINTS, MappingError, map_joints
from pipeline.motion.clip import Motion, resample
from pipeline.motion.rotations import quat_apply, quat_inv, quat_mul
from pipeline.usd.files import clean_dead_temps, saving, temp_path
from usd_schemas import tokens

SOURCE_NAMES_ATTR = tokens.SOURCE_JOINT_NAMES
_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_NOT_IDENT = re.compile(r"[^A-Za-z0-9_]+")


def usd_joint_names(names: tuple[str, ...] | list[str]) -> list[str]:
    """USD identifiers for joint names, unique, in the same order; deterministic.

    A name that already is an identifier (and not taken by an earlier joint) is kept, so
    Bandai and Character Creator rigs convert unchanged. Otherwise accents are dropped
    (``é`` → ``e``), every run of other characters becomes ``_`` (``spine.001`` →
    ``spine_001``, ``thigh.L`` → ``thigh_L``, ``mixamorig:Hips`` → ``mixamorig_Hips``:
    side markers stay separate words for the name-based mapper), a leading digit gets a
    ``_``, a name with nothing left is ``joint_<index>``, and a repeat gets ``_2``, ``_3``…
    """
    base, kept = [], []
    for j, n in enumerate(names):
        kept.append(bool(_IDENT.fullmatch(n)))
        if kept[-1]:
            base.append(n)
            continue
        ascii_ = unicodedata.normalize("NFKD", n).encode("ascii", "ignore").decode("ascii")
        b = _NOT_IDENT.sub("_", ascii_).strip("_") or f"joint_{j}"
        base.append(f"_{b}" if b[0].isdigit() else b)
    taken = set(base)
    out = [""] * len(base)
    used: set[str] = set()
    # Names kept as written are placed first, so a made-up name never takes theirs.
    for j in sorted(range(len(base)), key=lambda j: (not kept[j], j)):
        name, k = base[j], 2
        while name in used or (name != base[j] and name in taken):  # not another joint's name
            name, k = f"{base[j]}_{k}", k + 1
        out[j] = name
        used.add(name)
    return out


def rest_pose(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """Local rest rotations (J,4) and translations (J,3): the canonical T-pose when the rig
    maps onto the model skeleton, else the first frame.

    The first frame is also the fallback when the canonical pose cannot be built (a rig
    whose mapped joints sit on top of each other, like the CMU rig's zero-length
    ``LowerBack`` above ``Hips``, gives a reference pose that is not finite)."""
    from pipeline.adapt.retarget import model_rest, reference_pose
    from pipeline.data.skeletons import bandai_skeleton

    skel = motion.skeleton
    local = motion.rotations[0].astype(np.float64)
    trans = skel.offsets.astype(np.float64).copy()
    trans[0] = (0.0, float(motion.root_positions[0, 1]), 0.0)
    g, p = motion.slice(0, 1).fk()
    model = bandai_skeleton()
    if skel.names == model.names and np.array_equal(skel.parents, model.parents):
        # The model skeleton itself: its own canonical T-pose, the same for every clip, so a
        # copy of the shot re-oriented or renamed by another tool still carries the model's
        # frames in its rest pose (pipeline.adapt.retarget.model_rest).
        g = model_rest()
        local = np.array(
            [g[j] if q < 0 else quat_mul(quat_inv(g[q]), g[j]) for j, q in enumerate(skel.parents)]
        )
        return local, trans
    try:
        roles = map_joints(usd_joint_names(skel.names), skel.parents)
        with np.errstate(all="ignore"):
            ref = reference_pose(roles, g[0].astype(np.float64), p[0].astype(np.float64))
    except (MappingError, np.linalg.LinAlgError, ValueError, ZeroDivisionError):
        return local, trans
    mapped = [j for j, m in enumerate(MODEL_JOINTS) if m in roles]
    if not np.isfinite(ref[mapped]).all():
        return local, trans
    want = {roles[m]: ref[j] for j, m in enumerate(MODEL_JOINTS) if m in roles}
    gnew = np.empty_like(local)
    for j, par in enumerate(skel.parents):
        if j in want:
            gnew[j] = want[j]
            local[j] = gnew[j] if par < 0 else quat_mul(quat_inv(gnew[par]), gnew[j])
        else:
            gnew[j] = local[j] if par < 0 else quat_mul(gnew[par], local[j])
    return local, trans


def _box(a: np.ndarray, b: np.ndarray, r: float) -> np.ndarray:
    """8 corners of a box of half-width r around the segment a→b."""
    d = b - a
    n = np.linalg.norm(d)
    x = d / n
    h = np.array([0.0, 1.0, 0.0]) if abs(x[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    y = np.cross(x, h)
    y /= np.linalg.norm(y)
    z = np.cross(x, y)
    return np.array([a + s1 * r * y + s2 * r * z + e * d for e in (0, 1) for s1 in (-1, 1) for s2 in (-1, 1)])


_BOX_FACES = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]


def _world_pose(skel, rest_rot: np.ndarray, rest_trans: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each joint's rest rotation and position in the skeleton's space (J, 4), (J, 3)."""
    J = len(skel.parents)
    g_rot, g_pos = np.empty((J, 4)), np.empty((J, 3))
    for j, par in enumerate(skel.parents):
        if par < 0:
            g_rot[j], g_pos[j] = rest_rot[j], rest_trans[j]
        else:
            g_rot[j] = quat_mul(g_rot[par], rest_rot[j])
            g_pos[j] = g_pos[par] + quat_apply(g_rot[par], rest_trans[j])
    return g_rot, g_pos


def _define_skeleton(stage, motion: Motion, name: str):
    """The Skeleton prim: joints (and their BVH names where USD changed them), rest and bind
    transforms; returns it, the joints' rest positions and the joint tokens."""
    from pxr import Gf, Sdf, UsdSkel, Vt

    skel = motion.skeleton
    names = usd_joint_names(skel.names)
    paths: list[str] = []
    for j, par in enumerate(skel.parents):
        paths.append(names[j] if par < 0 else f"{paths[par]}/{names[j]}")
    tokens = Vt.TokenArray(paths)
    sk = UsdSkel.Skeleton.Define(stage, f"/World/{name}/Skel")
    sk.CreateJointsAttr(tokens)
    if names != list(skel.names):
        src = sk.GetPrim().CreateAttribute(SOURCE_NAMES_ATTR, Sdf.ValueTypeNames.StringArray, custom=True)
        src.Set(Vt.StringArray(list(skel.names)))
        src.SetDocumentation(
            "Joint names as written in the source BVH, one per entry of joints "
            "(whose last path elements are these names made into USD identifiers)."
        )
    rest_rot, rest_trans = rest_pose(motion)
    rest_m = [Gf.Matrix4d(Gf.Rotation(Gf.Quatd(float(q[3]), *map(float, q[:3]))), Gf.Vec3d(*map(float, t)))
              for q, t in zip(rest_rot, rest_trans, strict=False)]  # fmt: skip
    g_rot, g_pos = _world_pose(skel, rest_rot, rest_trans)
    bind_m = [Gf.Matrix4d(Gf.Rotation(Gf.Quatd(float(q[3]), *map(float, q[:3]))), Gf.Vec3d(*map(float, t)))
              for q, t in zip(g_rot, g_pos, strict=False)]  # fmt: skip
    sk.CreateRestTransformsAttr(Vt.Matrix4dArray(rest_m))
    sk.CreateBindTransformsAttr(Vt.Matrix4dArray(bind_m))
    return sk, g_pos, tokens


def _define_animation(stage, motion: Motion, name: str, sk, tokens, keys: list[int], start: float) -> None:
    """The SkelAnimation bound to ``sk``, sampled at the ``keys`` (frame indices)."""
    from pxr import Sdf, Usd, UsdSkel, Vt

    skel = motion.skeleton
    T, J = motion.rotations.shape[:2]
    anim = UsdSkel.Animation.Define(stage, f"/World/{name}/Skel/Anim")
    anim.CreateJointsAttr(tokens)
    UsdSkel.BindingAPI.Apply(sk.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    trans = np.broadcast_to(skel.offsets, (T, J, 3)).copy()
    trans[:, 0] = motion.root_positions
    ra, ta, sa = anim.CreateRotationsAttr(), anim.CreateTranslationsAttr(), anim.CreateScalesAttr()
    sa.Set(Vt.Vec3hArray.FromNumpy(np.ones((J, 3), np.float16)))
    with Sdf.ChangeBlock():
        for k in keys:
            t = Usd.TimeCode(start + k)
            ra.Set(Vt.QuatfArray.FromNumpy(np.ascontiguousarray(motion.rotations[k])), t)
            ta.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(trans[k].astype(np.float32))), t)


def write_shot(
    motion: Motion,
    out: str | Path,
    start: float = 1001,
    fps: float | None = None,
    keys_every: int = 1,
    up_axis: str = "Y",
    name: str = "Character",
) -> str:
    """Writes ``motion`` as a UsdSkel shot (atomically); returns the path."""
    from pxr import Usd, UsdGeom, UsdSkel

    out = Path(out)
    if fps:
        motion = resample(motion, fps)
    skel = motion.skeleton
    T = motion.rotations.shape[0]
    keys = list(range(0, T, max(1, keys_every)))
    if keys[-1] != T - 1:
        keys.append(T - 1)
    # Atomic: a temp named after this process (those of dead writers are removed), renamed
    # over ``out``; a full disk is one line naming ``out`` and leaves nothing behind.

    tmp = temp_path(out)
    clean_dead_temps(out.parent, quiet=True)
    with saving(out, tmp):
        stage = Usd.Stage.CreateNew(str(tmp))
    try:
        stage.SetTimeCodesPerSecond(motion.fps)
        stage.SetFramesPerSecond(motion.fps)
        stage.SetStartTimeCode(start)
        stage.SetEndTimeCode(start + T - 1)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z if up_axis.upper() == "Z" else UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, skel.meters_per_unit)
        world = UsdGeom.Xform.Define(stage, "/World")
        stage.SetDefaultPrim(world.GetPrim())
        root = UsdSkel.Root.Define(stage, f"/World/{name}")
        if up_axis.upper() == "Z":  # the BVH is Y up: stand the character up along Z
            UsdGeom.Xformable(root).AddRotateXOp().Set(90.0)
        sk, g_pos, tokens = _define_skeleton(stage, motion, name)
        _define_animation(stage, motion, name, sk, tokens, keys, start)
        _mannequin(stage, f"/World/{name}/Mannequin", sk, skel, g_pos, tokens)
        with saving(out, tmp):
            if not stage.GetRootLayer().Save():
                raise OSError(f"{out}: the shot was not saved")
            del stage
            os.replace(tmp, out)
    finally:
        if tmp.exists():
            tmp.unlink()
    return str(out)


def _mannequin(stage, path, sk, skel, g_pos, tokens) -> None:
    from pxr import Gf, UsdGeom, UsdSkel, Vt

    pts, idx, counts, faces = [], [], [], []
    for j, par in enumerate(skel.parents):
        if par < 0 or np.linalg.norm(g_pos[j] - g_pos[par]) < 1e-3:
            continue
        length = np.linalg.norm(g_pos[j] - g_pos[par])
        base = len(pts)
        pts.extend(_box(g_pos[par], g_pos[j], max(1.0, min(6.0, 0.18 * length))))
        idx.extend([par] * 8)
        for f in _BOX_FACES:
            counts.append(4)
            faces.extend(base + v for v in f)
    if not pts:  # every bone has zero length (a single joint): a small cube on the root
        c = g_pos[0]
        pts.extend(_box(c - (0.0, 2.0, 0.0), c + (0.0, 2.0, 0.0), 2.0))
        idx.extend([0] * 8)
        counts.extend([4] * 6)
        faces.extend(v for f in _BOX_FACES for v in f)
    mesh = UsdGeom.Mesh.Define(stage, path)
    pts = np.array(pts, np.float32)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray(counts))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(faces))
    mesh.CreateExtentAttr(
        Vt.Vec3fArray([Gf.Vec3f(*map(float, pts.min(0))), Gf.Vec3f(*map(float, pts.max(0)))])
    )
    binding = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    binding.CreateSkeletonRel().SetTargets([sk.GetPath()])
    binding.CreateJointIndicesPrimvar(False, 1).Set(Vt.IntArray([int(i) for i in idx]))
    binding.CreateJointWeightsPrimvar(False, 1).Set(Vt.FloatArray([1.0] * len(idx)))
    binding.CreateGeomBindTransformAttr(Gf.Matrix4d(1.0))
