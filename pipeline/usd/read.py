"""Reading a shot: every animated skeleton with its joints, rest/bind pose, keys and values.

Skeleton → animation bindings are resolved by UsdSkel's own cache (inherited
``skel:animationSource`` on a SkelRoot included). Matrices are converted to the column
convention on read (USD's are row-vector); quaternions are xyzw as everywhere here.

Bad content is refused here, before any work, as one ShotError line naming the prim and
time: an invalid skeleton topology, rest/bind transforms or animation samples that are not
finite, a rotation that is no quaternion (length ~0), a time code rate or stage range that
is not a positive finite span. USD's own warnings while the shot is read are captured
(:mod:`pipeline.usd.diagnostics`), kept off stderr and folded into the error line.
"""

from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import pipeline.usd  # noqa: F401  (registers the schema before any stage opens)
from pipeline.adapt.rig import Rig
from pipeline.errors import ShotError
from pipeline.inputs import not_a_file
from pipeline.motion.rotations import QUAT_EPS, matrix_to_quat
from pipeline.motion.skeleton import MAX_LENGTH, METERS_PER_UNIT
from pipeline.usd.diagnostics import error_text, short, usd_diagnostics
from pipeline.usd.keys import MAX_FRAMES
from usd_schemas import tokens

TIME_EPS = 1e-4  # time codes closer than this are the same frame (real files carry 3023.000157…)


@dataclass
class Character(Rig):
    """One animated skeleton of a shot: its rig (pipeline.adapt.rig.Rig: joints, rest and bind
    poses, the rest pose from restTransforms, the bind pose the FK of rest when not
    authored, skel_to_world at the start time) and where its animation lives."""

    shot: str
    skel_path: str
    anim_path: str
    anim_joints: tuple[str, ...]
    anim_index: np.ndarray  # (Ja,) skeleton index of each animation joint
    sample_times: np.ndarray  # authored samples of rotations ∪ translations
    key_override: np.ndarray | None = None  # tween:keyTimes on the animation
    blend_shapes: bool = False
    extra: dict = field(default_factory=dict)
    rot_times: np.ndarray | None = None  # authored samples of rotations alone
    trans_times: np.ndarray | None = None  # authored samples of translations alone
    keyed_joints: dict[float, tuple[str, ...]] | None = None  # tween:keyedJoints samples
    # Every joint the animation lists where some are not the skeleton's (UsdSkel ignores
    # those, and anim_joints leaves them out), and the entry of each anim_joint in its arrays.
    anim_authored: tuple[str, ...] | None = None
    anim_slots: np.ndarray | None = None
    # The skeleton's joints under roots other than the character's (check_topology): left out
    # of joints and anim_joints as the joints it lacks are, and kept in the fill as authored.
    other_joints: tuple[str, ...] = ()


@dataclass
class Shot:
    path: str
    stage: object
    tcps: float
    start: float
    end: float
    up_axis: str
    meters_per_unit: float
    characters: list[Character]


def _col(m) -> np.ndarray:
    """A Gf/Vt row-vector matrix (or array of them) as column-convention numpy."""
    return np.swapaxes(np.array(m, np.float64), -1, -2)


def _decompose(mats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (quats, scale removed by polar decomposition) and translation of (N,4,4)."""
    r = mats[:, :3, :3]
    u, _, vt = np.linalg.svd(r)
    rot = u @ vt
    flip = np.linalg.det(rot) < 0
    rot[flip] *= -1  # a mirrored bind matrix: keep a proper rotation; the humanoid check judges the pose
    return matrix_to_quat(rot), mats[:, :3, 3].copy()


def open_stage(path: str | Path):
    """The stage of a shot file, or a one-line ShotError."""
    from pxr import Tf, Usd

    path = str(path)
    if why := not_a_file(path, "shot file"):
        raise ShotError(path, why)
    try:
        path.encode("utf-8")
    except UnicodeEncodeError:  # usd-core takes UTF-8 paths only (raising deep inside it)
        raise ShotError(path, "its path is not UTF-8 text, which USD cannot open; rename it") from None
    with usd_diagnostics(path):
        try:
            odd, held = _not_files(path)  # a FIFO or device named as a layer: a stand-in, never read
            stage = Usd.Stage.Open(path, Usd.Stage.LoadAll)
        except Tf.ErrorException as e:
            raise ShotError(path, f"cannot open as USD: {error_text(e, path)}") from None
        if stage is None:
            raise ShotError(path, "cannot open as USD")
        stage.MuteAndUnmuteLayers(odd, [])  # out of GetUsedLayers (the digest reads those)
    with usd_diagnostics(path, fold=False):  # its own reason, not USD's warning appended
        _check_sublayers(stage, path)
    return stage


def _check_sublayers(stage, path: str) -> None:
    """ShotError where a sublayer of the stage is there but USD cannot read it (truncated,
    damaged): USD composes the stage without it and only warns, so a review of a fill layer
    cut short rendered the unfilled shot. A sublayer that is not there at all is a missing
    asset (:func:`missing_assets`), said and not refused."""
    from pxr import Sdf, Tf

    for layer in stage.GetLayerStack(includeSessionLayers=False):
        for sub in layer.subLayerPaths:
            where = layer.ComputeAbsolutePath(sub) if not layer.anonymous else sub
            if not where or not Path(where).is_file():
                continue
            try:
                ok = Sdf.Layer.FindOrOpen(where) is not None
            except Tf.ErrorException as e:
                raise ShotError(
                    path, f"its sublayer {where} cannot be read as USD: {error_text(e, where)}"
                ) from None
            if not ok:
                raise ShotError(path, f"its sublayer {where} cannot be read as USD")


def missing_assets(path: str | Path) -> list[str]:
    """The sublayers, references and payloads the shot (and the layers it brings in) names
    that cannot be found, or are there but no regular file (a folder, a device): USD
    composes the stage without them and warns at most, so a shot whose set or props did not
    load would otherwise fill without a word."""
    from pxr import UsdUtils

    path = str(path)
    # Its own warnings are what this returns; a file USD cannot parse is a one-line ShotError.
    with usd_diagnostics(path):
        odd, held = _not_files(path)
        found = UsdUtils.ComputeAllDependencies(path)[2]
        del held  # the stand-ins go once USD has followed the shot
        return sorted(set(found) | set(odd))


def _not_files(path: str) -> tuple[list[str], list]:
    """The sublayers, references and payloads of the shot's layers (followed as USD follows
    them, opening regular files only) that are there but no regular file (a link to nothing
    or a link loop among them), and the layers to hold while USD follows the shot: those
    read here, and an empty stand-in named as each such path that USD would open as a layer
    (its extension names a format), for reading a FIFO blocks and a device can read without
    end."""
    from pxr import Ar, Sdf, Tf, Usd

    def regular(p: str) -> bool | None:  # None: nothing there (USD lists it as unresolved)
        try:
            return Path(p).is_file() if Path(p).exists() else None
        except (OSError, ValueError):
            return None

    def dangling(p: str) -> bool:  # a link to nothing, or a link loop
        try:
            return Path(p).is_symlink() and not Path(p).exists()
        except (OSError, ValueError):
            return False

    if regular(path) is False:
        raise ShotError(path, not_a_file(path, "shot file"))
    odd, held, seen = [], [], {str(Path(path).absolute())}
    todo = [Sdf.Layer.FindOrOpen(path)]
    while todo:
        layer = todo.pop()
        held.append(layer)
        for dep in layer.GetCompositionAssetDependencies() if layer else ():
            where = layer.ComputeAbsolutePath(dep)
            if where in seen:
                continue
            seen.add(where)
            kind = regular(str(Ar.GetResolver().Resolve(where)) or where)
            if kind is None and dangling(where):
                kind = False  # USD resolves the link, fails to open it and only warns: said, not dropped
            is_layer = Usd.Stage.IsSupportedFile(where)
            if kind is False:
                odd.append(where)
                if is_layer:
                    fmt = Sdf.FileFormat.FindByExtension(where)
                    held.append(Sdf.Layer.Find(where) or Sdf.Layer.New(fmt, where))
            elif kind and is_layer:
                try:
                    sub = Sdf.Layer.FindOrOpen(where)
                except Tf.ErrorException:  # said where the stage is opened, or USD leaves it out
                    continue
                if sub is not None and not sub.GetFileFormat().IsPackage():
                    todo.append(sub)
    return odd, held


def _fk_bind(parents, rest_rot, rest_trans):
    from pipeline.motion.rotations import quat_apply, quat_mul

    J = len(parents)
    g_rot = np.zeros((J, 4))
    g_pos = np.zeros((J, 3))
    for j in range(J):
        p = parents[j]
        if p < 0:
            g_rot[j], g_pos[j] = rest_rot[j], rest_trans[j]
        else:
            g_rot[j] = quat_mul(g_rot[p], rest_rot[j])
            g_pos[j] = g_pos[p] + quat_apply(g_rot[p], rest_trans[j])
    return g_rot, g_pos


def _not_a_joint_path(token: str) -> str | None:
    """Why ``token`` names no joint (USD warns ``Ill-formed SdfPath`` of it), or None."""
    from pxr import Sdf

    try:
        ok, why = Sdf.Path.IsValidPathString(token)
    except UnicodeDecodeError:  # USD's reason quotes the name cut inside a character
        ok, why = False, "a character a prim name cannot hold"
    if ok and (Sdf.Path(token).IsAbsolutePath() or not Sdf.Path(token).IsPrimPath()):
        ok, why = False, "expected a relative prim path like Hips/Spine"
    return None if ok else short(why)


def check_topology(shot_path: str, skel_path: str, joints) -> np.ndarray | None:
    """Refuses a joint list UsdSkel cannot build a hierarchy from: a token that is not a
    relative prim path (USD warns ``Ill-formed SdfPath`` and drops the joint's parent), a
    joint listed twice, a parent listed after its child (``mis-ordered parent``), several
    root joints where no one hierarchy is the character (:func:`character_joints`).
    Returns the indices of the character's joints where there are several roots, else None."""
    from pxr import UsdSkel, Vt

    bad = "skeleton topology is invalid"
    if not joints:
        raise ShotError(shot_path, f"{bad}: the skeleton lists no joints", skel_path)
    seen: dict[str, int] = {}
    for i, t in enumerate(joints):
        why = _not_a_joint_path(t)
        if why:
            raise ShotError(shot_path, f"{bad}: joint {i} {t!r} is not a joint path: {why}", skel_path)
        if t in seen:
            raise ShotError(shot_path, f"{bad}: joint {i} {t!r} is joint {seen[t]} again", skel_path)
        seen[t] = i
    topology = UsdSkel.Topology(Vt.TokenArray(list(joints)))
    ok, why = topology.Validate()
    if not ok:
        raise ShotError(shot_path, f"{bad}: {short(why) or 'UsdSkel refuses it'}", skel_path)
    main, why = character_joints(list(joints), list(topology.GetParentIndices()))
    if why:
        raise ShotError(shot_path, f"skeleton topology: {why}", skel_path)
    return main


def _listed(names) -> str:
    """Root joints as topology_problem lists them: the first three, quoted."""
    return ", ".join(repr(r) for r in names[:3]) + (", ..." if len(names) > 3 else "")


def character_joints(joints: list[str], parents) -> tuple[np.ndarray | None, str | None]:
    """(the indices of the joints under the root holding the most joints, or None for one
    root; why no hierarchy is the character, or None).

    UsdSkel allows several roots, and real rigs have them (a Blender armature's unparented
    IK targets and poles, a Maya rig's prop or helper root): the fill takes the largest
    hierarchy as the character (its own-rig curves, retargeting and foot cleanup need one
    hierarchy) and the joints under the other roots as joints the skeleton lacks. Refused:
    two largest hierarchies of one size (neither is the character), and a root or joint
    under a joint path the skeleton does not list (a joint renamed or removed: the second
    root would be a piece of the character, left unfilled)."""
    parents = [int(p) for p in parents]
    roots = [j for j, p in enumerate(parents) if p < 0]
    if len(roots) < 2:
        return None, None
    head = f"{len(roots)} root joints ({_listed([joints[r] for r in roots])})"
    listed = set(joints)
    for t in joints:
        up = t.rpartition("/")[0]
        if up and up not in listed:
            return None, (
                f"{head}; joint {t!r} is under {up!r}, which the skeleton does not list (a joint "
                "renamed or removed?): a rig is one hierarchy under one root joint, and several "
                "roots are filled only as hierarchies of their own"
            )
    root_of = list(range(len(parents)))
    for j, p in enumerate(parents):  # parents come first (UsdSkel validated the order)
        if p >= 0:
            root_of[j] = root_of[p]
    size = {r: root_of.count(r) for r in roots}
    ranked = sorted(roots, key=lambda r: -size[r])
    if size[ranked[0]] == size[ranked[1]]:
        a, b = joints[ranked[0]], joints[ranked[1]]
        return None, (
            f"{head}; {a!r} and {b!r} each hold {size[ranked[0]]} joints, so neither is the "
            "character: the fill fills the hierarchy under the root holding the most joints"
        )
    return np.array([j for j in range(len(parents)) if root_of[j] == ranked[0]], np.int64), None


def _finite_matrices(shot_path: str, skel_path: str, name: str, mats: np.ndarray, joints) -> None:
    bad = ~np.isfinite(mats).all((1, 2))
    if bad.any():
        j = int(np.flatnonzero(bad)[0])
        raise ShotError(shot_path, f"{name}: NaN or infinite values (joint {joints[j]!r})", skel_path)


#: The value types UsdSkel poses its animation attributes from: with any other (``quatd[]``,
#: ``double3[]`` translations, ``float3[]`` scales...) its ``ComputeJointLocalTransforms``
#: returns nothing and every viewer shows the bind pose, so a fill of the values would show
#: what the shot never did (a ``float4[]`` rotation also reads x y z w as w x y z).
TYPES = {
    "rotations": ("quatf[]",),
    "translations": ("float3[]", "vector3f[]"),
    "scales": ("half3[]",),
}


def _check_type(shot_path: str, attr, anim_path: str) -> None:
    """ShotError naming the attribute when it is authored with a value type UsdSkel does not
    give it (the attribute itself takes its schema's type, whatever the specs say)."""
    allowed = TYPES[attr.GetName()]
    given = next((str(s.typeName) for s in attr.GetPropertyStack() if str(s.typeName) not in allowed), None)
    if given is not None:
        raise ShotError(
            shot_path, f"{attr.GetName()} is {given}, not {allowed[0]} (as UsdSkel declares it)", anim_path
        )


def check_samples(shot_path: str, anim, anim_path: str, anim_joints) -> None:
    """Every authored sample (or the default, when there are none) of the animation's
    rotations, translations and scales: one value per joint, finite, rotations of length
    above QUAT_EPS. Names the attribute, the time and the joint."""
    Ja = len(anim_joints)
    for attr in (anim.GetRotationsAttr(), anim.GetTranslationsAttr(), anim.GetScalesAttr()):
        name = attr.GetName()
        _check_type(shot_path, attr, anim_path)
        times = attr.GetTimeSamples()
        for t in times or [None]:
            v = attr.Get(t) if t is not None else attr.Get()
            if v is None:
                continue
            at = f"at time {t:g}" if t is not None else "in its default value"
            a = np.asarray(v, np.float64)
            if a.ndim != 2 or a.shape[0] != Ja:
                raise ShotError(shot_path, f"{name} holds {len(a)} values for {Ja} joints {at}", anim_path)
            finite = np.isfinite(a).all(1)
            if not finite.all():
                j = int(np.flatnonzero(~finite)[0])
                raise ShotError(
                    shot_path, f"{name}: NaN or infinite values {at} (joint {anim_joints[j]!r})", anim_path
                )
            far = (np.abs(a) > MAX_LENGTH).any(1)  # scales too: no character is 1e7 times itself
            if far.any():
                j = int(np.flatnonzero(far)[0])
                raise ShotError(
                    shot_path,
                    f"{name}: a value beyond ±{MAX_LENGTH:g} {at} (joint {anim_joints[j]!r})",
                    anim_path,
                )
            if name == "rotations":
                n = np.linalg.norm(a, axis=1)
                if (n <= QUAT_EPS).any():
                    j = int(np.flatnonzero(n <= QUAT_EPS)[0])
                    raise ShotError(
                        shot_path,
                        f"{name}: joint {anim_joints[j]!r} {at} is not a rotation "
                        f"(quaternion ({', '.join(f'{x:g}' for x in a[j])}) has length {n[j]:.3g})",
                        anim_path,
                    )


def _rest_and_bind(shot_path: str, skel, skel_path: str, joints: tuple, parents: np.ndarray):
    """The skeleton's rest pose (local rotations, translations) and bind pose (rotations,
    positions in skeleton space), each checked: (rest_rot, rest_trans, bind_rot, bind_pos)."""
    J = len(joints)
    rest = skel.GetRestTransformsAttr().Get()
    bind = skel.GetBindTransformsAttr().Get()
    for name, m in (("restTransforms", rest), ("bindTransforms", bind)):
        if m is not None and len(m) == J:
            _finite_matrices(shot_path, skel_path, name, _col(m), joints)
    if rest is not None and len(rest) == J:
        rest_rot, rest_trans = _decompose(_col(rest))
    elif bind is not None and len(bind) == J:
        # No rest pose: derive locals from the bind pose, as UsdSkel itself does.
        b = _col(bind)
        singular = np.abs(np.linalg.det(b[:, :3, :3])) < 1e-12
        if singular.any():
            j = int(np.flatnonzero(singular)[0])
            raise ShotError(
                shot_path,
                f"bindTransforms: the matrix of joint {joints[j]!r} is singular (no restTransforms to use)",
                skel_path,
            )
        loc = np.array([b[j] if parents[j] < 0 else np.linalg.inv(b[parents[j]]) @ b[j] for j in range(J)])
        rest_rot, rest_trans = _decompose(loc)
    else:
        raise ShotError(
            shot_path, f"skeleton has {J} joints but no rest or bind transforms for them", skel_path
        )
    if bind is not None and len(bind) == J:
        bind_rot, bind_pos = _decompose(_col(bind))
    else:
        bind_rot, bind_pos = _fk_bind(parents, rest_rot, rest_trans)
    return rest_rot, rest_trans, bind_rot, bind_pos


def _animation_joints(
    shot_path: str, anim, anim_path: str, joints: tuple, skel_path: str, character: set[str]
) -> tuple:
    """The joints the animation lists (each once), those of them the fill fills (the
    ``character``'s: the skeleton's, or its main hierarchy's where it has several roots), and
    a warning to say (once the shot is read) where some are not the skeleton's.

    UsdSkel maps an animation onto its skeleton by joint name and ignores the names the
    skeleton lacks (an animation of a larger rig, a joint deleted from the skeleton): so does
    the fill, with one warning; an animation naming none of the character's joints animates
    nothing the fill fills and is refused."""
    authored = tuple(str(t) for t in (anim.GetJointsAttr().Get() or []))
    if not authored:
        raise ShotError(shot_path, "animation lists no joints", anim_path)
    seen: set[str] = set()
    twice = next((t for t in authored if t in seen or seen.add(t)), None)  # the first repeat
    if twice is not None:  # UsdSkel would animate it from one entry and leave another joint still
        raise ShotError(shot_path, f"animation lists joint {twice!r} twice", anim_path)
    known = set(joints)
    missing = [t for t in authored if t not in known]
    for t in missing:  # a broken token, not a joint of another rig: refused as the skeleton's are
        if why := _not_a_joint_path(t):
            raise ShotError(shot_path, f"animation joint {t!r} is not a joint path: {why}", anim_path)
    filled = tuple(t for t in authored if t in character)
    if not filled:
        whose = f"its skeleton {skel_path}"
        if len(character) < len(known):  # it animates only joints under other roots
            root = next(t for t in character if "/" not in t)  # no gaps: the root's name
            whose = f"the hierarchy under {root!r} (the character) of its skeleton {skel_path}"
        raise ShotError(
            shot_path,
            f"animation lists none of the joints of {whose} (its first is {authored[0]!r})",
            anim_path,
        )
    warning = missing and (
        f"{len(missing)} of the animation's {len(authored)} joints "
        f"{'is' if len(missing) == 1 else 'are'} not in the skeleton {skel_path} "
        f"(the first is {missing[0]!r}); UsdSkel ignores them and so does the fill, "
        "which keeps their values as authored"
    )
    return authored, filled, warning


_WARNED: set[tuple] = set()


def _warn_once(shot_path: str, prim: str, text: str) -> None:
    """A warning line on stderr, said once a process for a version of the shot file: a fill
    reads its shot more than once (its check, then each take)."""
    try:
        version = os.stat(shot_path).st_mtime_ns
    except OSError:
        version = None
    said = (os.path.realpath(shot_path), version, prim, text)
    if said not in _WARNED:
        if len(_WARNED) > 1000:  # a farm worker lives long: bounded
            _WARNED.clear()
        _WARNED.add(said)
        print(f"tween: warning: {shot_path} {prim}: {text}", file=sys.stderr)


def _key_override(shot_path: str, anim_prim, anim_path: str) -> np.ndarray | None:
    """The animation's ``tween:keyTimes`` (the keys an animator named), or None."""
    kt = anim_prim.GetAttribute(tokens.KEY_TIMES)
    if not (kt and kt.HasAuthoredValue()):
        return None
    if kt.GetNumTimeSamples():
        raise ShotError(
            shot_path, "tween:keyTimes is time-sampled; it is one list of time codes (double[])", anim_path
        )
    try:
        override = np.array(kt.Get(), np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ShotError(
            shot_path,
            f"tween:keyTimes is {kt.GetTypeName()}; it is a list of time codes (double[])",
            anim_path,
        ) from None
    if not np.isfinite(override).all():
        raise ShotError(shot_path, "tween:keyTimes holds NaN or infinite time codes", anim_path)
    return override


def _character(shot_path: str, stage, skel, skelq, animq) -> Character:
    from pxr import UsdGeom, UsdSkel

    skel_path = str(skel.GetPrim().GetPath())
    anim_prim = animq.GetPrim()
    anim_path = str(anim_prim.GetPath())
    every = tuple(str(t) for t in skelq.GetJointOrder())
    joints, parents, poses, others, roots_note = _skeleton_joints(shot_path, skel, skel_path, skelq)
    rest_rot, rest_trans, bind_rot, bind_pos = poses

    anim = UsdSkel.Animation(anim_prim)
    authored, anim_joints, warning = _animation_joints(
        shot_path, anim, anim_path, every, skel_path, set(joints)
    )
    index = {t: i for i, t in enumerate(joints)}
    slot = {t: i for i, t in enumerate(authored)}
    # Every value authored is checked (the fill layer copies the extra joints' too).
    check_samples(shot_path, anim, anim_path, authored)
    rot_times = anim.GetRotationsAttr().GetTimeSamples()
    trans_times = anim.GetTranslationsAttr().GetTimeSamples()
    times = sorted(set(rot_times) | set(trans_times))
    override = _key_override(shot_path, anim_prim, anim_path)
    keyed = _keyed_joints(anim_prim, authored, shot_path, anim_path)
    start = stage.GetStartTimeCode()
    xf = UsdGeom.Xformable(skel.GetPrim()).ComputeLocalToWorldTransform(start)
    if not np.isfinite(np.array(xf)).all():
        raise ShotError(
            shot_path,
            f"the skeleton's world transform at time {start:g} holds NaN or infinite values",
            skel_path,
        )
    bs = anim.GetBlendShapeWeightsAttr()
    return Character(
        shot=shot_path,
        skel_path=skel_path,
        anim_path=anim_path,
        joints=joints,
        names=tuple(t.rsplit("/", 1)[-1] for t in joints),
        parents=parents,
        rest_rot=rest_rot,
        rest_trans=rest_trans,
        bind_rot=bind_rot,
        bind_pos=bind_pos,
        skel_to_world=_col(xf),
        anim_joints=anim_joints,
        anim_index=np.array([index[t] for t in anim_joints], np.int64),
        sample_times=np.array(times, np.float64),
        key_override=override,
        blend_shapes=bool(bs and bs.HasAuthoredValue()),
        rot_times=np.array(rot_times, np.float64),
        trans_times=np.array(trans_times, np.float64),
        keyed_joints=keyed,
        anim_authored=None if authored == anim_joints else authored,
        anim_slots=None if authored == anim_joints else np.array([slot[t] for t in anim_joints], np.int64),
        other_joints=others,
        extra={k: v for k, v in (("warning", warning), ("roots", roots_note)) if v},
    )


def _skeleton_joints(shot_path: str, skel, skel_path: str, skelq) -> tuple:
    """The character's joints, parents, (rest_rot, rest_trans, bind_rot, bind_pos), the
    skeleton's joints under other roots and the warning to say of them (None: one root)."""
    topo = skelq.GetTopology()
    every = tuple(str(t) for t in skelq.GetJointOrder())
    parents = np.array([topo.GetParent(i) for i in range(len(every))], np.int64)
    poses = _rest_and_bind(shot_path, skel, skel_path, every, parents)
    main = check_topology(shot_path, skel_path, list(every))
    if main is None:
        return every, parents, poses, (), None
    return _one_hierarchy(every, parents, poses, main)  # the character is one hierarchy


def _one_hierarchy(every: tuple, parents: np.ndarray, poses: tuple, main: np.ndarray):
    """The character's hierarchy ``main`` (:func:`character_joints`) of a skeleton of several
    roots: (its joints, parents renumbered, rest and bind poses, the skeleton's other joints,
    the warning to say): every user of the character sees one hierarchy under one root."""
    new = np.full(len(every), -1, np.int64)
    new[main] = np.arange(len(main))
    sub = np.where(parents[main] < 0, -1, new[np.maximum(parents[main], 0)])
    others = tuple(t for i, t in enumerate(every) if new[i] < 0)
    roots = [every[i] for i in np.flatnonzero(parents < 0)]
    one = len(others) == 1
    note = (
        f"{len(roots)} root joints ({_listed(roots)}): the character is the hierarchy under "
        f"{every[main[0]]!r} ({len(main)} joints); the {len(others)} joint{'' if one else 's'} under "
        f"the other roots (the first is {others[0]!r}) {'is' if one else 'are'} not filled and "
        f"{'keeps' if one else 'keep'} the animation's values as authored"
    )
    return tuple(every[i] for i in main), sub, tuple(a[main] for a in poses), others, note


def _keyed_joints(anim_prim, anim_joints, shot_path: str, anim_path: str):
    """{time: animation joints keyed there} from tween:keyedJoints, or None when not authored."""
    attr = anim_prim.GetAttribute(tokens.KEYED_JOINTS)
    if not attr or not attr.HasAuthoredValue():
        return None
    kind = str(attr.GetTypeName())
    if kind not in ("token[]", "string[]"):
        raise ShotError(
            shot_path, f"tween:keyedJoints is {kind}, not token[] (joint names per key)", anim_path
        )
    if not attr.GetNumTimeSamples():  # a default value names no key: it was silently ignored
        raise ShotError(
            shot_path,
            "tween:keyedJoints has no time samples: author the joints each key keys at its time",
            anim_path,
        )
    known, out = set(anim_joints), {}
    for t in attr.GetTimeSamples():
        names = tuple(str(x) for x in (attr.Get(t) or []))
        bad = [x for x in names if x not in known]
        if bad:
            raise ShotError(
                shot_path,
                f"tween:keyedJoints at time {t:g} names {bad[0]!r}, not a joint of the animation",
                anim_path,
            )
        out[float(t)] = names
    return out


def _check_rate(path: str, stage) -> float:
    tcps = float(stage.GetTimeCodesPerSecond())
    if not (tcps > 0 and math.isfinite(tcps)):
        root = stage.GetRootLayer()
        fps_only = not root.HasTimeCodesPerSecond() and root.HasFramesPerSecond()
        name = "framesPerSecond" if fps_only else "timeCodesPerSecond"
        raise ShotError(path, f"{name} {tcps:g} is not a positive number")
    return tcps


def check_span(path: str, start: float, end: float, what: str) -> None:
    """ShotError unless ``start``-``end`` is a finite range of at most MAX_FRAMES frames."""
    if not (math.isfinite(start) and math.isfinite(end)):
        raise ShotError(path, f"{what} {start:g}-{end:g} is not finite")
    if end < start:
        raise ShotError(path, f"{what} ends ({end:g}) before it starts ({start:g})")
    if end - start > MAX_FRAMES:
        raise ShotError(path, f"{what} {start:g}-{end:g} spans more than {MAX_FRAMES:,} frames")


def read_shot(path: str | Path, say: bool = True) -> Shot:
    """Every skeleton with a bound animation in the shot (UsdSkel binding resolution).
    USD's diagnostics while reading are captured, and folded into a refusal. ``say``: its
    warnings now (else the caller's :func:`say_warnings`, once its checks have passed)."""
    path = str(path)
    with usd_diagnostics(path):
        shot = _read_shot(path)
    if say:
        say_warnings(shot)
    return shot


@dataclass
class BoundSkeleton:
    """A skeleton with a bound animation, as UsdSkel resolves it."""

    root: object | None  # its SkelRoot prim; None outside any (Blender's mesh-less armature)
    skeleton: object  # UsdSkel.Skeleton
    query: object  # UsdSkel.SkelQuery (its GetAnimQuery() is the animation)
    skinned: list  # UsdSkel.SkinningQuery of each mesh bound to it


def bound_skeletons(stage, path: str) -> list[BoundSkeleton]:
    """Every skeleton of ``stage`` with a bound animation: the one character reader of the
    fill and the review. Under SkelRoots first (instance proxies included, so a character
    inside an instance is found), then skeletons outside any SkelRoot that bind an
    animation themselves. A skeleton meant to be animated whose joints make no hierarchy is
    a ShotError (UsdSkel only warns, and drops it)."""
    from pxr import Usd, UsdSkel

    pred = Usd.TraverseInstanceProxies()
    cache = UsdSkel.Cache()
    out: list[BoundSkeleton] = []
    seen: set[str] = set()

    def add(root, prim, skinned) -> None:
        skel = UsdSkel.Skeleton(prim)
        check_topology(path, str(prim.GetPath()), [str(t) for t in (skel.GetJointsAttr().Get() or [])])
        query = cache.GetSkelQuery(skel)
        if query and query.GetAnimQuery():
            seen.add(str(prim.GetPath()))
            out.append(BoundSkeleton(root, skel, query, skinned.get(str(prim.GetPath()), [])))

    for prim in stage.Traverse(pred):
        if not prim.IsA(UsdSkel.Root):
            continue
        root = UsdSkel.Root(prim)
        cache.Populate(root, pred)
        skinned = {
            str(b.GetSkeleton().GetPath()): list(b.GetSkinningTargets())
            for b in cache.ComputeSkelBindings(root, pred)
        }
        for sub in Usd.PrimRange(prim, pred):
            if sub.IsA(UsdSkel.Skeleton) and str(sub.GetPath()) not in seen:
                if UsdSkel.BindingAPI(sub).GetInheritedAnimationSource():
                    add(prim, sub, skinned)
    for prim in stage.Traverse(pred):
        if prim.IsA(UsdSkel.Skeleton) and str(prim.GetPath()) not in seen:
            if UsdSkel.BindingAPI(prim).GetAnimationSource():
                add(None, prim, {})
    return out


def binding_prim(path: str, skel_prim) -> str:
    """The prim on which the fill layer points a skeleton at its fill: the Skeleton itself, or,
    for a skeleton inside an instance (an instance proxy, on which no layer's opinion counts),
    the instance prim, from which it inherits the binding (a crowd's instances bind their
    animations so). ShotError when the binding it inherits is authored inside the instance: an
    opinion on the instance prim would not override it."""
    from pxr import UsdSkel

    inside, inst = [], skel_prim
    while inst.IsInstanceProxy():
        inside.append(inst)
        inst = inst.GetParent()
    if any(UsdSkel.BindingAPI(p).GetAnimationSourceRel().HasAuthoredTargets() for p in inside):
        raise ShotError(
            path, f"its animation is bound inside an instanced prim; set instanceable = false on "
            f"{inst.GetPath()} to fill it", str(skel_prim.GetPath()),
        )  # fmt: skip
    return str(inst.GetPath())


def _rig_difference(a: Character, b: Character) -> str | None:
    """How the rig of ``b`` differs from that of ``a`` for the values of an animation, joint
    by name (UsdSkel maps it so: the joint order may differ): a joint one lacks, another rest
    pose (the skeletons' places in the world may differ). None where they do not."""
    if set(a.joints) != set(b.joints):
        odd = sorted(set(a.joints) ^ set(b.joints))[0]
        return f"joint {odd!r} is in {a.skel_path if odd in a.joints else b.skel_path} only"
    # A joint's name is its path from its root: the same names are the same hierarchy.
    at = {t: i for i, t in enumerate(a.joints)}
    order = np.array([at[t] for t in b.joints], np.int64)  # a's index of each of b's joints
    size = max(1.0, float(np.abs(a.rest_trans).max()))
    bad = ~np.isclose(a.rest_trans[order], b.rest_trans, rtol=1e-5, atol=1e-5 * size).all(1)
    bad |= np.abs((a.rest_rot[order] * b.rest_rot).sum(1)) < 1 - 1e-6  # q and -q are one rotation
    if bad.any():
        return f"the rest pose of joint {b.joints[int(np.flatnonzero(bad)[0])]!r} differs"
    return None


def _check_shared(path: str, chars: list[Character]) -> None:
    """ShotError where skeletons bound to one animation differ as rigs: the fill fills a
    shared animation once, on the first skeleton's rig, and binds every one to that fill (a
    crowd's instances on one cycle); the same values on another rest pose or hierarchy are
    another motion, which the fill never judged (its feet, its model's retargeting)."""
    first: dict[str, Character] = {}
    for c in chars:
        a = first.setdefault(c.anim_path, c)
        why = None if a is c else _rig_difference(a, c)
        if why:
            raise ShotError(
                path, f"skeletons {a.skel_path} and {c.skel_path} share this animation but not a rig "
                f"({why}); the fill fills it once, on one rig: give each skeleton its own SkelAnimation",
                c.anim_path,
            )  # fmt: skip


def _read_shot(path: str) -> Shot:
    from pxr import UsdGeom

    stage = open_stage(path)
    tcps = _check_rate(path, stage)
    if stage.HasAuthoredTimeCodeRange():
        check_span(path, stage.GetStartTimeCode(), stage.GetEndTimeCode(), "the stage range")
    bound = bound_skeletons(stage, path)
    for b in bound:
        anim = b.query.GetAnimQuery().GetPrim()
        if anim.IsInPrototype():  # a fill's overs there would land on a prototype no layer may name
            inst = b.skeleton.GetPrim()
            while inst and not inst.IsInstance():
                inst = inst.GetParent()
            where = inst.GetPath() if inst else "its instance"
            raise ShotError(
                path, f"its animation is inside an instanced prim; set instanceable = false on {where} to fill it",
                str(b.skeleton.GetPath()),
            )  # fmt: skip
        binding_prim(path, b.skeleton.GetPrim())
    chars = [_character(path, stage, b.skeleton, b.query, b.query.GetAnimQuery()) for b in bound]
    _check_shared(path, chars)
    if not chars:
        raise ShotError(path, "no SkelRoot holds a skeleton with a bound SkelAnimation")
    up = str(UsdGeom.GetStageUpAxis(stage))
    if up not in ("Y", "Z"):  # UsdGeom allows these two; anything else was read as Z
        raise ShotError(path, f"upAxis {up!r} is not an up axis USD knows (Y or Z)")
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    lo, hi = METERS_PER_UNIT
    if not lo <= mpu <= hi:  # NaN fails too
        raise ShotError(
            path, f"metersPerUnit {mpu:g} is not a unit a character is measured in ({lo:g} to {hi:g} m)"
        )
    start, end = stage.GetStartTimeCode(), stage.GetEndTimeCode()
    if not stage.HasAuthoredTimeCodeRange():
        allt = np.concatenate([c.sample_times for c in chars if len(c.sample_times)] or [np.zeros(1)])
        start, end = float(allt.min()), float(allt.max())
        check_span(path, start, end, "the animation's time samples")
    return Shot(path, stage, tcps, float(start), float(end), up, mpu, chars)


#: The value of an attribute an animation never authors, for the joints its skeleton lacks
#: (UsdSkel ignores those joints: any value shows the same).
UNAUTHORED = {"rotations": (0, 0, 0, 1), "translations": (0, 0, 0), "scales": (1, 1, 1)}


def rest_values(stage, skel: str, authored: list[str]) -> dict:
    """Per attribute, (len(authored), 3 or 4) values: the skeleton's rest pose (UsdSkel's
    local rest transforms, decomposed) for the joints it has, UNAUTHORED for the others.
    What an attribute the animation never authors shows: UsdSkel poses nothing from an
    animation that lacks one, so the original showed those joints at rest."""
    from pxr import Usd, UsdSkel

    out = {n: np.tile(np.array(v, np.float64), (len(authored), 1)) for n, v in UNAUTHORED.items()}
    query = UsdSkel.Cache().GetSkelQuery(UsdSkel.Skeleton(stage.GetPrimAtPath(skel)))
    local = query.ComputeJointLocalTransforms(Usd.TimeCode.Default(), True) if query else None
    if not local:
        return out
    trans, rots, scales = UsdSkel.DecomposeTransforms(local)
    at = {str(t): i for i, t in enumerate(query.GetJointOrder())}
    for name, values in (("rotations", rots), ("translations", trans), ("scales", scales)):
        values = np.array(values, np.float64)
        for j, t in enumerate(authored):
            if t in at:
                out[name][j] = values[at[t]]
    return out


def say_warnings(shot: Shot, roots_line=None) -> None:
    """The reader's warnings of ``shot`` (several roots, joints the skeleton lacks), each once
    a process for a version of the file: said by the caller once its own checks have passed,
    so that a refusal is its one line. ``roots_line(character)``: the several-roots line a
    fill says instead of the reader's (pipeline.usd.follow.roots_line: which kept controls
    follow a filled joint)."""
    for c in shot.characters:
        if c.extra.get("roots"):
            _warn_once(shot.path, c.skel_path, c.extra["roots"] if roots_line is None else roots_line(c))
        if c.extra.get("warning"):
            _warn_once(shot.path, c.anim_path, c.extra["warning"])


def anim_values(stage, char: Character, times) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Animation-ordered local (rotations f32 xyzw, translations f32, scales f16) at ``times``.

    Values between authored samples are USD's own interpolation (SLERP / LERP). An
    attribute with no value at all falls back to the rest pose, as UsdSkel does.
    """
    with usd_diagnostics(char.shot):
        return _anim_values(stage, char, times)


def _anim_values(stage, char: Character, times):
    from pxr import UsdSkel

    anim = UsdSkel.Animation(stage.GetPrimAtPath(char.anim_path))
    Ja = len(char.anim_joints)
    listed = len(char.anim_authored or char.anim_joints)  # the entries each authored array holds
    slots = slice(None) if char.anim_slots is None else char.anim_slots
    T = len(times)
    rot = np.empty((T, Ja, 4), np.float32)
    tr = np.empty((T, Ja, 3), np.float32)
    sc = np.empty((T, Ja, 3), np.float16)
    attrs = (
        (anim.GetRotationsAttr(), rot, char.rest_rot[char.anim_index]),
        (anim.GetTranslationsAttr(), tr, char.rest_trans[char.anim_index]),
        (anim.GetScalesAttr(), sc, np.ones((Ja, 3))),
    )
    for attr, out, fallback in attrs:
        for i, t in enumerate(times):
            v = attr.Get(float(t))
            if v is None:
                out[i] = fallback
                continue
            a = np.array(v)
            if a.shape[0] != listed:
                raise ShotError(
                    char.shot,
                    f"{attr.GetName()} holds {a.shape[0]} values for {listed} joints at time {t:g}",
                    char.anim_path,
                )
            out[i] = a[slots]
    return rot, tr, sc


def to_skeleton_order(char, rot_a, tr_a):
    """Animation-ordered locals → skeleton order (joints the animation lacks keep rest)."""
    T = rot_a.shape[0]
    rot = np.broadcast_to(char.rest_rot.astype(np.float32), (T,) + char.rest_rot.shape).copy()
    tr = np.broadcast_to(char.rest_trans.astype(np.float32), (T,) + char.rest_trans.shape).copy()
    rot[:, char.anim_index] = rot_a
    tr[:, char.anim_index] = tr_a
    return rot, tr
