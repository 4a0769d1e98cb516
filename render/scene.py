"""What a review renders, read from a composed stage with plain Usd/UsdSkel API.

Every animated skeleton in the stage becomes a :class:`Character`; its geometry is the stage's
own skinned meshes (UsdSkel linear blend skinning) or, when nothing is bound to it, a mannequin
of capsules built from its joints. Everything is returned in metres, Y up.
"""

from __future__ import annotations

import re
import sys
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np

from pipeline.errors import ShotError
from pipeline.usd.keys import key_distance
from render import mannequin
from render.geometry import Geometry
from render.overlays import timecode
from usd_schemas import tokens

TAKE_VARIANT_SET = tokens.TAKE_VARIANT_SET
#: The facts that describe the fill as a whole (the MP4's comment); the others are per gap.
SUMMARY_FACTS = ("model", "model_hash", "take", "seed")
FACT_ATTRS = {
    "model": tokens.MODEL,
    "model_hash": tokens.MODEL_HASH,
    "take": tokens.TAKE,
    "seed": tokens.SEED,
    "trust_gaps": tokens.TRUST_GAPS,
    "trust_gap_weights": tokens.TRUST_GAP_WEIGHTS,
    "library_gaps": tokens.LIBRARY_GAPS,
    "library_share": tokens.LIBRARY_SHARE,
    "trust_evidence": tokens.TRUST_EVIDENCE,  # its "source": the in-betweener the probes chose
}


NEAR = 1e-4  # a rate or step this close to a whole number (or NTSC n*1000/1001) is that number


@dataclass(frozen=True)
class Timing:
    """How a shot's time codes become output frames.

    ``tcps`` and ``fps`` are the stage's timeCodesPerSecond and framesPerSecond as authored
    (fps falls back to tcps when only tcps is authored: Blender writes no framesPerSecond);
    ``rate`` is the playback rate as a sensible fraction (30.0000304 -> 30, 29.97 -> 30000/1001);
    ``step`` the time codes per output frame (snapped to a whole number, or 1/n, when within
    ``NEAR`` of one, so a near-integer rate neither drops nor doubles frames).
    """

    tcps: float
    fps: float
    rate: Fraction
    step: float


def _snap_rate(fps: float) -> Fraction:
    cands = [Fraction(round(fps)), Fraction(round(fps * 1.001) * 1000, 1001)]
    best = min(cands, key=lambda c: abs(float(c) - fps))
    if best > 0 and abs(float(best) - fps) <= NEAR * max(fps, 1.0):
        return best
    return Fraction(fps).limit_denominator(1001)


def _snap_step(step: float) -> float:
    if step >= 1:
        return float(round(step)) if abs(step - round(step)) <= NEAR else step
    k = round(1.0 / step)
    return 1.0 / k if k and abs(1.0 / step - k) <= NEAR else step


#: The fastest playback a review renders (frames a second); high-frame-rate capture is 120–240.
MAX_RATE = 1000


def shot_timing(stage) -> Timing:
    """The stage's :class:`Timing`, from what is authored on the root/session layer.

    ``stage.GetFramesPerSecond()`` answers 24 when nothing is authored, which would play a
    30 time-codes-per-second Blender shot at 24 fps and skip every fifth time code.
    """
    pseudo = stage.GetPseudoRoot()
    tcps = float(stage.GetTimeCodesPerSecond())  # USD itself falls back to fps, then 24
    fps = float(stage.GetFramesPerSecond()) if pseudo.HasAuthoredMetadata("framesPerSecond") else tcps
    if not fps > 0 or not tcps > 0:
        fps = tcps = fps if fps > 0 else (tcps if tcps > 0 else 24.0)
    return Timing(tcps, fps, _snap_rate(fps), _snap_step(tcps / fps))


def frame_times(start: float, end: float, timing: Timing) -> tuple[np.ndarray, np.ndarray]:
    """(time codes, frame numbers) of the output frames from ``start`` to ``end`` inclusive.

    One frame every ``timing.step`` time codes; frame numbers are the (rounded) time codes when
    a frame spans at least one time code, else consecutive numbers from the first.
    """
    step = timing.step
    n = int(np.floor((end - start) / step + 1e-6)) + 1
    times = start + step * np.arange(max(n, 1))
    frames = np.round(times).astype(int) if step >= 1 else int(round(start)) + np.arange(len(times))
    return times, frames


def timecodes(times, timing: Timing) -> list[str]:
    """Non-drop HH:MM:SS:FF of each time code: its time in seconds (t / tcps) counted in frames
    at the playback rate, so time code 261 of a 30.0000304 tcps shot is 00:00:08:21."""

    rate = float(timing.rate)
    counts = np.floor(np.asarray(times, np.float64) / timing.tcps * rate + 0.5).astype(int)  # halves up
    return [timecode(int(c), rate) for c in counts]


_HIPS = re.compile(r"(^|[^a-z])(hips?|pelvis)([^a-z]|$)")
STATIC_M = 1e-4  # a joint that moves less than this (metres, skeleton space) over the shot is static


def body_joint(positions: np.ndarray, parents, names) -> int:
    """The joint that carries the character through the shot (the hips): its ground path and
    KEY ring are drawn.

    1. A joint named hips/pelvis (``Hips``, ``mixamorig:Hips``, ``Bip01 Pelvis``) above at
       least half of the skeleton (so ``Left_Hip`` never wins); the one above the most joints.
    2. Otherwise, from the root above the most joints, down to the child above the most joints
       while the joint stays still (``positions`` (T, J, 3) move less than ``STATIC_M``) and
       something below it moves: a static root bone (Blender's armature root) is not followed.
    A shot whose joint 0 is the hips keeps joint 0.
    """
    parents = np.asarray(parents)
    J = len(parents)
    desc = np.zeros(J, int)
    for j in range(J - 1, -1, -1):  # UsdSkel orders parents before children
        if 0 <= parents[j] < J:
            desc[parents[j]] += desc[j] + 1
    named = [j for j, n in enumerate(names) if _HIPS.search(str(n).lower()) and desc[j] * 2 >= J - 1]
    if named:
        return max(named, key=lambda j: (desc[j], -j))
    pos = np.asarray(positions, np.float64)
    moves = np.ptp(pos, axis=0).max(-1) > STATIC_M if len(pos) else np.zeros(J, bool)
    below_moves = moves.copy()
    for j in range(J - 1, -1, -1):
        if 0 <= parents[j] < J and below_moves[j]:
            below_moves[parents[j]] = True
    roots = [j for j in range(J) if not 0 <= parents[j] < J]
    j = max(roots, key=lambda r: (desc[r], -r)) if roots else 0
    while not moves[j]:
        kids = [k for k in range(J) if parents[k] == j and below_moves[k]]
        if not kids:
            break
        j = max(kids, key=lambda k: (desc[k], -k))
    return int(j)


@dataclass
class Character:
    skel_path: str
    anim_path: str
    key_times: np.ndarray
    facts: dict
    _skel_query: object = field(repr=False)
    _skinning: list = field(repr=False)
    _world: np.ndarray = field(repr=False)  # stage -> metres Y up (4x4, row vectors)
    body: int = 0  # the joint whose path is drawn on the ground (see body_joint)


@dataclass
class Shot:
    name: str
    path: str
    fps: float
    times: np.ndarray  # time codes rendered, one per output frame
    frames: np.ndarray  # the shot's own frame numbers (int)
    key_times: np.ndarray
    facts: dict
    take: str | None
    characters: list[Character]
    stage: object = field(repr=False)
    props: list = field(default_factory=list, repr=False)  # unskinned meshes under animated SkelRoots
    world: np.ndarray = field(default_factory=lambda: np.eye(4), repr=False)
    timing: Timing | None = None

    def timecodes(self) -> list[str]:
        """SMPTE time code of every output frame (at the shot's playback rate)."""
        return timecodes(self.times, self.timing or Timing(self.fps, self.fps, Fraction(self.fps), 1.0))

    def is_key(self, tol: float | None = None) -> np.ndarray:
        """(T,) bool: frames within a small tolerance of a key (time codes may be non-integer)."""
        step = float(np.median(np.diff(self.times))) if len(self.times) > 1 else 1.0
        tol = 0.01 * step if tol is None else tol
        if not len(self.key_times):
            return np.zeros(len(self.times), bool)
        return key_distance(self.times, self.key_times) <= tol

    def held_times(self) -> np.ndarray:
        """Stepped blocking: each frame's time code replaced by the last key at or before it."""
        keys = np.sort(self.key_times)
        if not len(keys):
            return self.times.copy()
        step = float(np.median(np.diff(self.times))) if len(self.times) > 1 else 1.0
        i = np.searchsorted(keys, self.times + 0.01 * step, side="right") - 1
        return keys[np.clip(i, 0, len(keys) - 1)]


def shot_label(stage_path: str) -> str:
    """``sh010`` for ``sh010.usda``; ``sh010 v003`` for the review layer ``sh010.review.v003.usda``."""
    fname = Path(stage_path).name
    m = re.match(r"^(?P<shot>[^.]+)\.review\.(?P<ver>v\d+)\.usd[acz]?$", fname)
    return f"{m['shot']} {m['ver']}" if m else fname.split(".")[0]


def list_takes(stage_path: str) -> list[int]:
    """Take numbers N of the ``takeN`` variants of the stage's ``tweenTake`` set ([] if none)."""
    from pxr import Usd

    stage = Usd.Stage.Open(stage_path, load=Usd.Stage.LoadNone)
    for prim in stage.Traverse(Usd.PrimAllPrimsPredicate):
        vsets = prim.GetVariantSets()
        if vsets.HasVariantSet(TAKE_VARIANT_SET):
            names = vsets.GetVariantSet(TAKE_VARIANT_SET).GetVariantNames()
            return sorted(int(n[4:]) for n in names if re.fullmatch(r"take\d+", n))
    return []


def _single_takes(stage) -> set[int]:
    """The take numbers a fill without takes variants recorded on its animations (``tween:take``)."""
    from pxr import Usd

    out = set()
    for p in stage.Traverse(Usd.PrimAllPrimsPredicate):
        a = p.GetAttribute(tokens.TAKE) if p.GetTypeName() == "SkelAnimation" else None
        if a and a.HasAuthoredValue():
            out.add(int(a.Get()))
    return out


def _select_take(stage, path: str, take: int | None) -> str | None:
    from pxr import Usd

    holders = [
        p
        for p in stage.Traverse(Usd.PrimAllPrimsPredicate)
        if p.GetVariantSets().HasVariantSet(TAKE_VARIANT_SET)
    ]
    if take is None:
        if holders:
            return holders[0].GetVariantSets().GetVariantSet(TAKE_VARIANT_SET).GetVariantSelection() or None
        return None
    if not holders:
        single = _single_takes(stage)
        if take in single:  # a fill of one take has no variant set; it is that take
            return None
        held = (
            f"its fill is take {', '.join(map(str, sorted(single)))} alone"
            if single
            else "it holds no fill's takes"
        )
        raise ShotError(
            path, f"--take {take} given but {held} (no prim has a {TAKE_VARIANT_SET!r} variant set)"
        )
    name = f"take{take}"
    # Select in the session layer: the user's files are never edited.
    stage.SetEditTarget(stage.GetSessionLayer())
    for prim in holders:
        vset = prim.GetVariantSets().GetVariantSet(TAKE_VARIANT_SET)
        names = vset.GetVariantNames()
        if name not in names:
            raise ShotError(path, f"no take {take} (variants: {', '.join(names)})", str(prim.GetPath()))
        vset.SetVariantSelection(name)
    return name


def take_names(stage_path: str, takes: list[int | None]) -> list[str | None]:
    """The take name each of ``takes`` renders as (``takeN``; for None the stage's own
    selection, None without takes): what ``open_shot`` calls it, from one opening of the
    stage. ShotError, as ``open_shot``'s, for a take the stage does not hold."""
    stage = _open_stage(stage_path)
    # None reads the stage's selection: before a take number selects another in the session layer
    names = {t: _select_take(stage, stage_path, t) for t in sorted(set(takes), key=lambda t: t is not None)}
    return [names[t] for t in takes]


def _stage_to_metres_yup(stage) -> np.ndarray:
    from pxr import UsdGeom

    m = np.eye(4)
    if UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z:
        # (x, y, z) -> (x, z, -y): Z-up stages stand up in the Y-up viewer.
        m[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    s = UsdGeom.GetStageMetersPerUnit(stage)
    return m @ np.diag([s, s, s, 1.0])


def _attr(prim, name):
    a = prim.GetAttribute(name)
    return a.Get() if a and a.HasAuthoredValue() else None


def _character(stage, path, skel, query, skinning, world) -> Character | None:
    anim = query.GetAnimQuery()
    if not anim or not anim.GetPrim():
        return None
    aprim = anim.GetPrim()
    keys = _attr(aprim, tokens.KEY_TIMES)
    if keys is None:
        from pxr import UsdSkel

        rot = UsdSkel.Animation(aprim).GetRotationsAttr() if aprim.IsA(UsdSkel.Animation) else None
        samples = rot.GetTimeSamples() if rot else anim.GetJointTransformTimeSamples()
        keys = samples
    facts = {k: _attr(aprim, a) for k, a in FACT_ATTRS.items()}
    facts = {k: v for k, v in facts.items() if v is not None}
    if not len(anim.GetJointTransformTimeSamples()) and not len(keys):
        return None  # bound to a static pose: nothing to review
    return Character(
        str(skel.GetPath()),
        str(aprim.GetPath()),
        np.asarray(keys, np.float64),
        facts,
        query,
        skinning,
        world,
        _body(query, anim.GetJointTransformTimeSamples(), float(np.linalg.norm(world[0, :3]))),
    )


def _body(query, samples, metres: float, n: int = 64) -> int:
    """:func:`body_joint` from skeleton-space joint positions (times ``metres`` per unit) at up
    to ``n`` of the animation's samples, over the whole shot (not just the frames rendered)."""
    names = [str(j).split("/")[-1] for j in query.GetJointOrder()]
    parents = np.asarray(query.GetTopology().GetParentIndices())
    samples = list(samples) or [0.0]
    pick = np.unique(np.linspace(0, len(samples) - 1, min(n, len(samples))).round().astype(int))
    pos = np.stack([np.array(query.ComputeJointSkelTransforms(samples[i]))[:, 3, :3] for i in pick])
    return body_joint(pos * metres, parents, names)


def _open_stage(stage_path: str):
    """The USD stage of ``stage_path``, every payload loaded, or a ShotError saying why not:
    the fill's own opening (pipeline.usd.read.open_stage), so that a layer of it USD cannot
    parse (a truncated fill layer under a review root) is that error, not a review of the
    shot without it."""
    from pipeline.usd.read import open_stage

    return open_stage(stage_path)


def _characters_and_props(stage, stage_path: str, world) -> tuple[list[Character], list]:
    """The animated characters of ``stage``, and the unskinned meshes beside them (props)."""
    from pxr import Usd, UsdGeom

    from pipeline.usd.read import bound_skeletons  # pxr (and the TweenAPI plugin)

    # The fill's own character reader: SkelRoots (instance proxies included) and skeletons
    # outside any SkelRoot that bind an animation (Blender's mesh-less armatures).
    chars: list[Character] = []
    props: list = []
    by_root: dict[str, list] = {}
    for b in bound_skeletons(stage, stage_path):
        c = _character(stage, stage_path, b.skeleton, b.query, b.skinned, world)
        if c is not None:
            chars.append(c)
            if b.root is not None:
                by_root.setdefault(str(b.root.GetPath()), [b.root, set()])[1].update(
                    str(q.GetPrim().GetPath()) for q in b.skinned
                )
    # Unskinned meshes beside an animated character (an instrument's base, a prop) are drawn
    # as they are, so the performance is seen in its setting.
    for root, skinned in by_root.values():
        props.extend(
            m for m in Usd.PrimRange(root)
            if m.IsA(UsdGeom.Mesh) and str(m.GetPath()) not in skinned
            and UsdGeom.Imageable(m).ComputeVisibility() != UsdGeom.Tokens.invisible
        )  # fmt: skip
    return chars, props


def _time_range(stage, stage_path: str, chars: list[Character], frame_range) -> tuple[float, float]:
    """The time codes to render: the stage's authored range, else its animations' samples,
    within ``frame_range`` if given."""
    if stage.HasAuthoredTimeCodeRange():
        start, end = stage.GetStartTimeCode(), stage.GetEndTimeCode()
    else:
        samples = [t for c in chars for t in c._skel_query.GetAnimQuery().GetJointTransformTimeSamples()]
        start, end = (min(samples), max(samples)) if samples else (0.0, 0.0)
    if frame_range is not None:
        lo, hi = max(start, frame_range[0]), min(end, frame_range[1])
        if hi < lo:
            raise ShotError(stage_path, f"frame range {frame_range} is outside the shot")
        if (lo, hi) != tuple(frame_range):  # said, not silently cut: the MP4 is shorter than asked
            a, b = frame_range
            print(f"tween: {stage_path}: --frames {a:g}:{b:g} reaches past the shot's {start:g}-{end:g}; "
                  f"rendering {lo:g}-{hi:g}", file=sys.stderr)  # fmt: skip
        start, end = lo, hi
    from pipeline.usd.read import check_span  # pxr

    # The fill's own bound on a shot's span: the review holds every frame's pose in memory.
    check_span(stage_path, start, end, "the range to render" + (" (--frames)" if frame_range else ""))
    return start, end


def open_shot(
    stage_path: str,
    take: int | None = None,
    frame_range: tuple[float, float] | None = None,
    name: str | None = None,
) -> Shot:
    """Opens ``stage_path`` (never writing to it), selects the take and finds the animated skeletons."""
    stage = _open_stage(stage_path)
    take_name = _select_take(stage, stage_path, take)
    world = _stage_to_metres_yup(stage)
    chars, props = _characters_and_props(stage, stage_path, world)
    if not chars:
        raise ShotError(
            stage_path, "no animated skeleton (SkelRoot > Skeleton with a SkelAnimation) to render"
        )

    timing = shot_timing(stage)
    if timing.rate > MAX_RATE:  # 100,000 fps: 97 frames took minutes in the camera's smoothing
        raise ShotError(stage_path, f"plays at {float(timing.rate):g} frames a second (framesPerSecond); a review "
                        f"plays at most {MAX_RATE} (author the shot's playback rate)")  # fmt: skip
    times, frames = frame_times(*_time_range(stage, stage_path, chars, frame_range), timing)

    key_times = np.unique(np.concatenate([c.key_times for c in chars]))
    facts: dict = {}
    for c in chars:
        for k, v in c.facts.items():
            facts.setdefault(k, v)
    if take_name and "take" not in facts:
        facts["take"] = take_name
    shot_name = name or shot_label(stage_path)
    return Shot(
        shot_name,
        str(stage_path),
        float(timing.rate),
        times,
        frames,
        key_times,
        facts,
        take_name,
        chars,
        stage,
        props,
        world,
        timing,
    )


def _apply(points: np.ndarray, m: np.ndarray) -> np.ndarray:
    return points @ m[:3, :3] + m[3, :3]


def evaluate(shot: Shot, times: np.ndarray) -> tuple[list[Geometry], list[np.ndarray]]:
    """Geometry of every character at ``times`` (metres, Y up) and each one's body path (T, 3):
    the path of its :func:`body_joint` (the hips), not of joint 0.

    Joint positions are computed for every frame now (small); skinned points per frame on demand.
    """
    from pxr import UsdGeom

    times = np.asarray(times, np.float64)
    uniq, inv = np.unique(times, return_inverse=True)
    geoms: list[Geometry] = []
    roots: list[np.ndarray] = []
    for c in shot.characters:
        q = c._skel_query
        skel_prim = UsdGeom.Imageable(q.GetSkeleton().GetPrim())
        joints = _joints(c, uniq)
        roots.append(joints[inv, c.body].astype(np.float32))
        if c._skinning:
            skin = _SkinCache(q, skel_prim, c._world)
            for sq in c._skinning:
                n = len(_mesh_points(sq, uniq[0]))

                def fn(i, sq=sq, skin=skin):
                    return skin.points(sq, float(times[i])), None

                geoms.append(Geometry(_triangles(sq.GetPrim(), shot.path), n, len(times), fn))
        else:
            parents = np.asarray(q.GetTopology().GetParentIndices())
            names = [str(j).split("/")[-1] for j in q.GetJointOrder()]
            # No capsule from a static root bone to the hips (it would lie across the set).
            above = set()
            j = int(parents[c.body])
            while j >= 0:
                above.add(j)
                j = int(parents[j])
            man = mannequin.Mannequin(joints[inv].astype(np.float32), parents, names, skip_from=above)
            geoms.append(man.geometry())
    for prim in shot.props:
        mesh, img = UsdGeom.Mesh(prim), UsdGeom.Imageable(prim)
        n = len(np.asarray(mesh.GetPointsAttr().Get(uniq[0]) or []))
        if not n:
            continue

        def prop_frame(i, mesh=mesh, img=img, n=n):
            t = float(times[i])
            pts = np.asarray(mesh.GetPointsAttr().Get(t) or [], np.float64).reshape(-1, 3)
            if len(pts) != n:  # topology changes over time: keep the first frame's points count
                pts = np.resize(pts, (n, 3))
            return _apply(pts, np.array(img.ComputeLocalToWorldTransform(t)) @ shot.world).astype(
                np.float32
            ), None

        geoms.append(Geometry(_triangles(prim, shot.path), n, len(times), prop_frame))
    return geoms, roots


def _joints(c: Character, times: np.ndarray) -> np.ndarray:
    from pxr import UsdGeom

    q = c._skel_query
    skel_prim = UsdGeom.Imageable(q.GetSkeleton().GetPrim())
    joints = np.empty((len(times), len(q.GetJointOrder()), 3), np.float64)
    for i, t in enumerate(times):
        to_world = np.array(skel_prim.ComputeLocalToWorldTransform(t)) @ c._world
        joints[i] = _apply(np.array(q.ComputeJointSkelTransforms(t))[:, 3, :3], to_world)
    return joints


def joint_positions(shot: Shot, times=None) -> list[np.ndarray]:
    """Every character's joint positions (T, J, 3) at ``times`` (default: the frames rendered),
    in metres, Y up: the world the renderer draws (and projects with its camera)."""
    times = shot.times if times is None else np.asarray(times, np.float64)
    return [_joints(c, times) for c in shot.characters]


class _SkinCache:
    """Skinning transforms of one skeleton for the last time asked (shared by its meshes)."""

    def __init__(self, query, skel_prim, world):
        self.q, self.skel_prim, self.world, self.t, self.xf, self.to_world = (
            query,
            skel_prim,
            world,
            None,
            None,
            None,
        )

    def points(self, sq, t: float) -> np.ndarray:
        if t != self.t:
            self.t, self.xf = t, self.q.ComputeSkinningTransforms(t)
            self.to_world = np.array(self.skel_prim.ComputeLocalToWorldTransform(t)) @ self.world
        return _apply(_skinned(sq, self.xf, t), self.to_world).astype(np.float32)


def _mesh_points(sq, t) -> np.ndarray:
    from pxr import UsdGeom

    pts = UsdGeom.Mesh(sq.GetPrim()).GetPointsAttr().Get(t)
    return np.asarray(pts if pts is not None else [], np.float32).reshape(-1, 3)


def _skinned(sq, xf, t) -> np.ndarray:
    from pxr import UsdGeom, Vt

    pts = UsdGeom.Mesh(sq.GetPrim()).GetPointsAttr().Get(t)
    if sq.IsRigidlyDeformed():
        m = np.array(sq.ComputeSkinnedTransform(xf, t))
        return _apply(np.asarray(pts, np.float64), m)
    pts = Vt.Vec3fArray(pts)
    sq.ComputeSkinnedPoints(xf, pts, t)  # in place, into skeleton space
    return np.asarray(pts, np.float64)


def _triangles(prim, path) -> np.ndarray:
    """Fan triangulation of the mesh's faces (numpy; usd-core has no triangulation helper in Python)."""
    from pxr import UsdGeom

    mesh = UsdGeom.Mesh(prim)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(), np.int64)
    idx = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), np.int64)
    if counts.sum() != len(idx):
        raise ShotError(path, "faceVertexCounts do not add up to faceVertexIndices", str(prim.GetPath()))
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    ntri = np.maximum(counts - 2, 0)
    face = np.repeat(np.arange(len(counts)), ntri)
    k = np.arange(ntri.sum()) - np.repeat(np.cumsum(ntri) - ntri, ntri) + 1
    s = starts[face]
    return np.stack([idx[s], idx[s + k], idx[s + k + 1]], axis=1).astype(np.int32)
