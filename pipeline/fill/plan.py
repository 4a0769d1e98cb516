"""Validating a shot and planning its fill: characters, keys, fill range and retargeters.

Each character gets a model: a stored per-rig model when its skeleton fits one exactly
(:mod:`pipeline.rig.store`; checked first, it wins), otherwise the human model through the
joint mapping and retargeting, otherwise it is refused with a hint to train a rig model.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field

import numpy as np

from pipeline.adapt.mapping import REQUIRED, MappingError, load_override, map_joints
from pipeline.adapt.retarget import Retarget
from pipeline.adapt.rigmap import OwnRig, RigMap, skeleton_space
from pipeline.errors import ShotError, TweenError
from pipeline.fill.jumps import body_centre, jump_line, key_jumps
from pipeline.rig import store
from pipeline.rig.store import no_model_hint
from pipeline.usd.follow import keys_around, roots_line
from pipeline.usd.keys import MAX_JOINT_FRAMES, key_distance, merge_times, parse_keys, parse_range
from pipeline.usd.read import (
    QUAT_EPS,
    TIME_EPS,
    Character,
    Shot,
    anim_values,
    read_shot,
    say_warnings,
    to_skeleton_order,
)

#: The most model frames one character's keys may span (the in-betweener fills them all).
MAX_MODEL_FRAMES = 1_000_000


@dataclass
class CharPlan:
    char: Character
    retarget: Retarget | RigMap | OwnRig
    keys: np.ndarray  # key time codes (exact authored values where they are samples)
    fill_range: tuple[float, float]
    model: str | None = None  # a rig model folder; None = the job's human model
    fps: float = 30.0  # the frame rate of this character's model
    authored_keys: bool = False  # keys are the animation's own samples (not --keys / tween:keyTimes)
    jumps: list[dict] = field(default_factory=list)  # key pairs the body teleports between (fill.jumps)
    # Other skeletons bound to its animation: it is filled once, and every one rebound to it.
    also: list[str] = field(default_factory=list)

    def retarget_info(self) -> dict:
        """How the character reaches its model: the reference pose mapped through and the
        model joints its rig lacks (provenance for the layer and the JSON)."""
        rt = self.retarget
        if isinstance(rt, RigMap):
            return {"reference": "rig model", "missing": []}
        return {"reference": rt.reference, "missing": list(rt.missing)}


#: ``make_plan(rig=...)``: look for a stored rig model first (the default), or never.
RIG_AUTO, RIG_OFF = "auto", "off"


@dataclass
class Plan:
    shot: Shot
    chars: list[CharPlan]
    refused: list[tuple[str, str]]  # (prim, why)
    model_fps: float
    notes: list[str] = field(default_factory=list)  # said once every check has passed

    def say(self) -> None:
        """The shot's reading warnings, its notes and the characters it skipped, on stderr."""
        # The several-roots warning says which kept controls follow a joint over the keys
        # the fill fills between, as the writer judges them.
        keys = {c.char.anim_path: keys_around(c.keys, *c.fill_range) for c in self.chars}
        # A character not filled (a rig refused) keeps the reader's line.
        said = {c.char.anim_path: c.char for c in self.chars}
        say_warnings(
            self.shot,
            lambda c: (
                roots_line(self.shot.stage, c, keys[c.anim_path])
                if said.get(c.anim_path) is c
                else c.extra["roots"]
            ),
        )
        for note in self.notes:
            print(note, file=sys.stderr)
        for prim, why in self.refused:
            print(f"tween: warning: {self.shot.path} {prim}: skipped: {why}", file=sys.stderr)

    def summary(self) -> dict:
        return {
            "shot": self.shot.path,
            "tcps": self.shot.tcps,
            "start": self.shot.start,
            "end": self.shot.end,
            "up_axis": self.shot.up_axis,
            "meters_per_unit": self.shot.meters_per_unit,
            "characters": [c.char.anim_path for c in self.chars],
            "skeletons": {c.char.anim_path: [c.char.skel_path, *c.also] for c in self.chars},
            "keys": {c.char.anim_path: [float(k) for k in c.keys] for c in self.chars},
            "range": {c.char.anim_path: [float(x) for x in c.fill_range] for c in self.chars},
            "refused": [{"prim": p, "reason": r} for p, r in self.refused],
            "rig_models": {c.char.anim_path: c.model for c in self.chars if c.model},
            "retarget": {c.char.anim_path: c.retarget_info() for c in self.chars},
            "jumps": {c.char.anim_path: c.jumps for c in self.chars},
        }


def _key_jumps(path, shot: Shot, c: Character, k, rt, keyed, notes: list[str]) -> list[dict]:
    """The key pairs ``c``'s body teleports between (fill.jumps), said in ``notes``; none on a
    creature's own rig model (the bounds are a human's). ``keyed``: the keys' skeleton-order
    rotations and translations."""
    if isinstance(rt, RigMap):
        return []
    up, mpu = skeleton_space(c, shot.up_axis, shot.meters_per_unit)
    centre = body_centre(c.parents, *keyed) * mpu
    jumps = key_jumps(k, centre, shot.tcps, {"Y": 1, "Z": 2}.get(up))
    if jumps:
        notes.append(f"tween: warning: {path} {c.anim_path}: {jump_line(jumps)}")
    return jumps


def _shares_a_fill(chars: list[CharPlan], c: Character) -> bool:
    """Whether ``c``'s animation is planned already (skeletons sharing an animation, a crowd's
    instances on one cycle, share its fill): then ``c``'s skeleton is rebound to it too."""
    same = next((p for p in chars if p.char.anim_path == c.anim_path), None)
    if same is not None:
        same.also.append(c.skel_path)
    return same is not None


def _every_frame_keyed(path: str, c: Character, k: np.ndarray, notes: list[str]) -> None:
    """A warning where ``c``'s keys are its authored samples and those lie on every frame (a
    DCC's export samples every frame: Blender's does): every frame is then a key and nothing
    is in-betweened, which the fill said nothing of (it wrote a layer of the keys alone)."""
    if len(k) > 2 and np.all(np.diff(k) <= 1 + TIME_EPS):
        notes.append(
            f"tween: warning: {path} {c.anim_path}: a sample on every frame from {k[0]:g} to {k[-1]:g} and "
            f"no keys named, so every frame is a key and nothing is in-betweened; name the keys with "
            f"--keys (e.g. --keys {k[0]:g}-{k[-1]:g}x10) or tween:keyTimes on the animation"
        )


def _keys_for(shot: Shot, char: Character, want: np.ndarray | None) -> np.ndarray:
    """``want``: the parsed --keys, or None (tween:keyTimes, else the authored samples)."""
    if want is None and char.key_override is not None:
        want = np.unique(char.key_override)
    elif want is None:
        return char.sample_times
    # Snap requested keys onto authored samples within tolerance so they keep exact values.
    return merge_times(char.sample_times[key_distance(char.sample_times, want) < TIME_EPS], want)


def _rig_for(shot: Shot, c: Character, rig: str):
    """(RigMap, folder) for ``c`` on a rig model, or (None, why not) when none fits."""

    up, mpu = skeleton_space(c, shot.up_axis, shot.meters_per_unit)
    if not up:
        return None, None if rig == RIG_AUTO else "the stage's up axis is X or down in skeleton space"
    lengths = np.linalg.norm(c.rest_trans, axis=-1) * mpu
    if rig == RIG_AUTO:
        found = store.find_rig(c.names, c.parents, lengths)
        if found is None:
            return None, None
        info, perm = found
    else:
        info = store.read_rig_json(rig)
        perm, why = store.match_rig(info, c.names, c.parents, lengths)
        if perm is None:
            return None, f"does not fit rig model {info.name} ({info.folder}): {why}"
    return RigMap(c, info, perm, up, mpu), str(info.folder)


def own_rate(tcps: float, keys: np.ndarray) -> float:
    """The rate a character is interpolated at on its own rig: the shot's, or a multiple
    of it fine enough that no two keys (sub-frame time codes included) share a frame."""
    for n in (1, 2, 4, 8, 16, 32):
        if len(np.unique(np.round((keys - keys[0]) * n))) == len(keys):
            return float(tcps * n)
    return float(tcps * 64)


def _check_key_values(path: str, c: Character, k: np.ndarray, rot, tr, sc) -> None:
    """The values at every key: finite, rotations of length above QUAT_EPS (the samples
    themselves were checked on read; keys between samples are USD's interpolation)."""
    fin = np.isfinite(rot).all((1, 2)) & np.isfinite(tr).all((1, 2)) & np.isfinite(sc).all((1, 2))
    if not fin.all():
        raise ShotError(path, f"NaN or infinite values at time {k[~fin][0]:g}", c.anim_path)
    short = np.linalg.norm(rot.astype(np.float64), axis=-1) <= QUAT_EPS
    if short.any():
        i, j = (int(x[0]) for x in np.nonzero(short))
        raise ShotError(
            path,
            f"rotations: joint {c.anim_joints[j]!r} at time {k[i]:g} is not a rotation (length ~0)",
            c.anim_path,
        )


def _retarget_for(
    path: str,
    shot,
    c: Character,
    k: np.ndarray,
    pose,
    model_fps: float,
    rig: str,
    own_rig: bool,
    override,
    notes,
):
    """How character ``c`` (keyed at ``k``, ``pose`` its key rotations and translations in
    skeleton order) reaches a model: (retarget, rig model folder or None, model rate), or
    (None, why, None) where it is refused (make_plan's ``rig``, ``own_rig``)."""
    rt, folder, fps = None, None, model_fps
    if own_rig:
        return OwnRig(c), None, own_rate(shot.tcps, k)
    if rig != RIG_OFF:
        rt, folder = _rig_for(shot, c, rig)
        if rt is None and rig != RIG_AUTO:
            return None, folder, None
        if rt is not None:
            return rt, folder, rt.info.fps
    try:
        roles = map_joints(c.joints, c.parents, override, c.other_joints)
        rt = Retarget(c, roles, shot.up_axis, shot.meters_per_unit, (k, *pose))
    except MappingError as e:
        why = str(e)
        # A rig model is the way for a creature: a rig whose pose is not a human's, or whose
        # names place no arm or leg joint at all; never for a human rig that only needs some
        # joints named.
        limbs = {r for r in REQUIRED if r not in ("Hips", "Head")}
        creature = why.startswith("not a humanoid") or limbs <= set(e.unplaced)
        if rig == RIG_AUTO and creature:
            why += "; " + no_model_hint(path, c.skel_path, c.names)
        return None, why, None
    if rt.missing:
        notes.append(
            f"tween: {path} {c.skel_path}: the rig has no {', '.join(rt.missing)}: "
            "held at the model's typical pose"
        )
    return rt, folder, fps


def _check_key_frames(path: str, shot, c: Character, k: np.ndarray, fps: float, notes: list) -> None:
    """ShotError unless the keys ``k`` lie in the stage range, span at most MAX_MODEL_FRAMES
    frames at ``fps`` and fall on at least two model frames, no two sub-frame keys sharing
    one; a note where whole-frame keys share one (a shot above the model's rate)."""
    lo, hi = shot.start - TIME_EPS, shot.end + TIME_EPS
    out = k[(k < lo) | (k > hi)]
    if len(out):
        raise ShotError(
            path, f"key {out[0]:g} is outside the stage range {shot.start:g}-{shot.end:g}", c.anim_path
        )
    span = (k[-1] - k[0]) / shot.tcps * fps
    if not span <= MAX_MODEL_FRAMES:
        raise ShotError(
            path,
            f"keys {k[0]:g}-{k[-1]:g} span {span:.0f} frames at {fps:g} fps "
            f"(timeCodesPerSecond {shot.tcps:g}); at most {MAX_MODEL_FRAMES:,}",
            c.anim_path,
        )
    m = np.round((k - k[0]) / shot.tcps * fps)
    dup = np.nonzero(np.diff(m) == 0)[0]
    close = dup[np.diff(k)[dup] < 1 - TIME_EPS]
    if len(close):  # sub-frame keys closer than the model's frame: refused, as asked
        a, b = k[close[0]], k[close[0] + 1]
        raise ShotError(
            path, f"keys {a:.10g} and {b:.10g} fall on one model frame (1/{fps:g} s)", c.anim_path
        )
    if len(np.unique(m)) < 2:  # nothing left between the keys at the model's rate
        raise ShotError(
            path,
            f"keys {k[0]:.10g}-{k[-1]:.10g} all fall on one model frame (1/{fps:g} s): "
            "at least two frames apart are needed",
            c.anim_path,
        )
    if len(dup):  # a shot above the model's rate keyed on consecutive frames: the
        # network sees one key a model frame, and every key keeps its values
        a, b = k[dup[0]], k[dup[0] + 1]
        more = f" and {len(dup) - 1} more pair(s)" if len(dup) > 1 else ""
        notes.append(
            f"tween: {path} {c.anim_path}: keys {a:.10g} and {b:.10g}{more} fall on one model "
            f"frame (1/{fps:g} s): the network sees one key there; every key keeps its values"
        )


def _check_size(path: str, c: Character, fr: tuple[float, float]) -> None:
    """ShotError where the fill range ``fr`` holds more than MAX_JOINT_FRAMES joint-frames of
    ``c``: refused before the minutes it ran and the memory it ran out of."""
    frames = int(np.floor(fr[1] + TIME_EPS) - np.ceil(fr[0] - TIME_EPS)) + 1
    joints = max(len(c.joints), len(c.anim_joints))
    if frames * joints > MAX_JOINT_FRAMES:
        raise ShotError(
            path, f"the fill range {fr[0]:g}-{fr[1]:g} is {frames:,} frames of {joints:,} joints, over "
            f"{MAX_JOINT_FRAMES:,} joint-frames (about 4 GB to fill): fill it in parts with --range",
            c.anim_path,
        )  # fmt: skip


def make_plan(
    path: str,
    keys: str | None,
    range_: str | None,
    mapping: str | None,
    model_fps: float,
    rig: str = RIG_OFF,
    own_rig: bool = False,
    say: bool = True,
) -> Plan:
    """``model_fps`` is the human model's rate; ``rig`` is RIG_AUTO (a stored rig model that
    fits a character wins over the human mapping), RIG_OFF (human model only) or a rig
    model folder (that model only); ``own_rig``: every character on its own rig, mapped or
    not (interpolation needs no model skeleton). ``say``: its notes now (else :meth:`Plan.say`)."""
    shot = read_shot(path, say=False)  # its warnings with the plan's notes: a refusal is one line
    try:
        override = load_override(mapping)
    except MappingError as e:
        raise TweenError(str(e)) from None
    # Options are checked against the stage before a range of them is expanded.
    want = parse_keys(keys, path, shot.start, shot.end) if keys else None
    rng = parse_range(range_, path, shot.start, shot.end) if range_ else None
    chars: list[CharPlan] = []
    refused: list[tuple[str, str]] = []
    notes: list[str] = []  # said on stderr once every check has passed (one line on refusal)
    for c in shot.characters:
        if _shares_a_fill(chars, c):
            continue
        k = _keys_for(shot, c, want)
        if len(k) < 2:
            raise ShotError(path, f"animation has {len(k)} key(s); at least two are needed", c.anim_path)
        rot, tr, sc = anim_values(shot.stage, c, k)
        _check_key_values(path, c, k, rot, tr, sc)
        srot, strans = to_skeleton_order(c, rot, tr)
        rt, folder, fps = _retarget_for(
            path, shot, c, k, (srot, strans), model_fps, rig, own_rig, override, notes
        )
        if rt is None:
            refused.append((c.skel_path, folder))
            continue
        _check_key_frames(path, shot, c, k, fps, notes)
        jumps = _key_jumps(path, shot, c, k, rt, (srot, strans), notes)
        fr = rng or (float(k[0]), float(k[-1]))
        if fr[1] < shot.start - TIME_EPS or fr[0] > shot.end + TIME_EPS:
            raise ShotError(
                path, f"range {fr[0]:g}-{fr[1]:g} is outside the stage range {shot.start:g}-{shot.end:g}"
            )
        _check_size(path, c, fr)
        authored = not keys and c.key_override is None
        if authored:
            _every_frame_keyed(path, c, k, notes)
        chars.append(CharPlan(c, rt, k, fr, folder, float(fps), authored_keys=authored, jumps=jumps))
    if not chars:
        prim, why = refused[0]
        raise ShotError(path, f"rig refused: {why}", prim)
    plan = Plan(shot, chars, refused, model_fps, notes)
    if say:
        plan.say()
    return plan
