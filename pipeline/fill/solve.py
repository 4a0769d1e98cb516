"""Filling one character: keys → model skeleton at the model rate → in-betweener → back
onto the shot's rig at every shot frame, keys carrying their authored values bitwise. The
human model's trusted fill blends, gap by gap, its network's fill turned back onto the rig
with the spline filled on the rig itself (the trusted fill's curve, infer.trust.trusted_curve)."""

from __future__ import annotations

import numpy as np

from pipeline.adapt.rigmap import OwnRig
from pipeline.errors import ShotError
from pipeline.fill.plan import MAX_MODEL_FRAMES, CharPlan, Plan, own_rate
from pipeline.infer.trust import TrustedInbetweener, blend_arrays, gap_weights_at, trusted, trusted_fill
from pipeline.motion.clip import Motion
from pipeline.motion.rotations import quat_normalize
from pipeline.usd.keys import merge_times
from pipeline.usd.read import TIME_EPS, anim_values, to_skeleton_order

# Shot frames a fill turns back onto the rig at once (fill_character).
SOLVE_BLOCK = 8192


def _slerp_frames(q: np.ndarray, i0: np.ndarray, w: np.ndarray) -> np.ndarray:
    """q[i0]…q[i0+1] at per-frame weights w; rotations.slerp takes one weight list for all
    pairs, this one a weight per frame. w == 0 returns q[i0] unchanged."""
    i1 = np.minimum(i0 + 1, len(q) - 1)
    a = q[i0].astype(np.float64)
    b = q[i1].astype(np.float64)
    dot = (a * b).sum(-1, keepdims=True)
    b = np.where(dot < 0, -b, b)
    dot = np.clip(np.abs(dot), 0.0, 1.0)
    ww = w[:, None, None]
    theta = np.arccos(dot)
    near = (1 - dot) < 1e-6
    st = np.where(near, 1.0, np.sin(theta))
    s0 = np.where(near, 1 - ww, np.sin((1 - ww) * theta) / st)
    s1 = np.where(near, ww, np.sin(ww * theta) / st)
    out = quat_normalize(s0 * a + s1 * b)
    exact = w == 0
    out[exact] = q[i0[exact]]
    return out


def model_frames(keys: np.ndarray, tcps: float, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """(m, keep): the model frame of each key time code, and the keys the in-betweener is
    given, one a model frame. Keys on one model frame (a 60 fps shot keyed on consecutive
    frames; the plan refuses sub-frame keys that collide) share it: the key nearest to the
    frame's time stands for them all (the first on a tie). Every key still gets its authored
    values afterwards; where the two keys differ (a pop rather than a hold) the fill on the
    far side of the one left out starts from the other, so it jumps at that key."""
    t = (keys - keys[0]) / tcps * fps
    m = np.round(t).astype(np.int64)
    order = np.lexsort((np.abs(t - m), m))  # by frame, then offset (stable: the first on a tie)
    first = np.r_[True, np.diff(m[order]) != 0]
    return m, order[first]


def model_time(times: np.ndarray, keys: np.ndarray, tcps: float, fps: float) -> np.ndarray:
    """The (fractional) model frame of each time code: ``fps`` frames a second from the first
    key, moved gap by gap so that every key the in-betweener is given falls on the model frame
    :func:`model_frames` gives it. A key between two model frames (every key of a 24 fps shot
    keyed every 10 frames is 12.5 model frames from the last) is filled at the nearer one;
    read at the rate alone, the fill would put that key, and the motion into and out of it,
    up to half a model frame off its time. Keys on model frames keep the rate's mapping as it is."""
    t = (times - keys[0]) / tcps * fps
    m, keep = model_frames(keys, tcps, fps)
    off = (keys[keep] - keys[0]) / tcps * fps - m[keep]
    if np.abs(off).max() < 1e-6:
        return t
    return t - np.interp(times, keys[keep], off)


def jump_gaps(cp: CharPlan, tcps: float, fps: float) -> list[tuple[int, int]]:
    """The key pairs the character's body teleports between (``cp.jumps``), as the model
    frames :func:`model_frames` gives those keys."""
    if not cp.jumps:
        return []
    m = model_frames(cp.keys, tcps, fps)[0]
    at = {float(t): int(f) for t, f in zip(cp.keys, m, strict=True)}
    return [(at[j["from"]], at[j["to"]]) for j in cp.jumps]


def frames_in(lo: float, hi: float) -> np.ndarray:
    return np.arange(np.ceil(lo - TIME_EPS), np.floor(hi + TIME_EPS) + 1, dtype=np.float64)


def rig_key_channels(cp: CharPlan) -> tuple[np.ndarray, np.ndarray] | None:
    """The animation's partial keys on its own rig: (K, J_rig) keyed joint rotations and (K,)
    keyed translations, or None when every key is a full pose.

    A key is partial where rotations and translations are sampled at different times, or
    where ``tween:keyedJoints`` names the joints whose rotations it keys (joints the
    animation lacks hold their rest: keyed). Only for the animation's own samples (keys
    given with --keys or tween:keyTimes are full poses, as asked); the first and last keys
    stay full, their missing channels taken at USD's interpolated value."""
    c, k = cp.char, cp.keys
    if not cp.authored_keys or c.rot_times is None or c.trans_times is None:
        return None

    def at(times):  # an attribute with no samples holds one value: keyed everywhere
        if len(times) == 0:
            return np.ones(len(k), bool)
        # The nearest sample on either side (not a keys × samples table: long shots).
        t = np.sort(np.asarray(times))
        i = np.searchsorted(t, k)
        below, above = t[np.maximum(i - 1, 0)], t[np.minimum(i, len(t) - 1)]
        return np.minimum(np.abs(k - below), np.abs(k - above)) < TIME_EPS

    rot, trans = at(c.rot_times), at(c.trans_times)
    rig = np.repeat(rot[:, None], len(c.joints), 1)
    for t, tokens in (c.keyed_joints or {}).items():
        for i in np.flatnonzero((np.abs(k - t) < TIME_EPS) & rot):
            rig[i, c.anim_index] = np.isin(c.anim_joints, tokens)
    rig[[0, -1]], trans[[0, -1]] = True, True
    return None if rig.all() and trans.all() else (rig, trans)


def key_channels(cp: CharPlan, rig_keys: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray | None:
    """``rig_keys`` (from :func:`rig_key_channels`) for the model skeleton: (K, J + 1), the
    joints' rotations, then the root position (the retargeter says which model channels the
    keyed rig channels determine), or None when every key is a full pose for the model."""
    if rig_keys is None:
        return None
    mask = cp.retarget.model_channels(*rig_keys)
    return None if mask.all() else mask


def _keyed_motion(
    plan: Plan, cp: CharPlan, keyed, retarget, skeleton, fps: float
) -> tuple[Motion, np.ndarray]:
    """The character's keys on ``skeleton`` (through ``retarget``) at ``fps``: a Motion over
    the key span whose key frames hold the keys (the frames between any value: they are
    filled), and the model frames of the keys it holds (one a model frame: model_frames).
    ``keyed``: the rig's rotations and translations at every key (``anim_values`` at
    ``cp.keys``, read once by the caller)."""
    c = cp.char
    m, keep = model_frames(cp.keys, plan.shot.tcps, fps)
    rot_k, tr_k = (v[keep] for v in keyed)
    loc_k, root_k = retarget.to_model(*to_skeleton_order(c, rot_k, tr_k))
    m = m[keep]
    T = int(m[-1]) + 1
    near = np.clip(np.searchsorted(m, np.arange(T)), 0, len(m) - 1)  # any value; frames off keys are filled
    motion = Motion(skeleton, loc_k[near], root_k[near], fps, c.anim_path)
    motion.rotations[m], motion.root_positions[m] = loc_k, root_k
    return motion, m


def _onto_rig(plan: Plan, cp: CharPlan, retarget, fps: float, filled: Motion | None, m: np.ndarray) -> dict:
    """A fill on the model skeleton (at ``fps``, keyed at model frames ``m``:
    :func:`_keyed_motion`) turned back onto the rig through ``retarget``; None (nothing
    filled) gives no ``rot``/``tr``. Returns the fill range's time codes ``inside``, their
    model frames ``u``, the keys' model frames ``m``, and the rig's ``rot``/``tr``/``sc``
    there."""
    shot, c = plan.shot, cp.char
    k = cp.keys
    T = int(m[-1]) + 1
    lo, hi = cp.fill_range
    inside = merge_times(k[(k >= lo - TIME_EPS) & (k <= hi + TIME_EPS)], frames_in(lo, hi))
    u = np.clip(model_time(inside, k, shot.tcps, fps), 0, T - 1)
    out = {"inside": inside, "u": u, "m": m, "rot": None, "tr": None}
    if filled is None:
        out["sc"] = anim_values(shot.stage, c, inside)[2]
        return out
    i0 = np.floor(u + 1e-9).astype(np.int64)
    w = np.clip(u - i0, 0.0, 1.0)
    w[w < 1e-7] = 0.0
    # Frame by frame from here on: long shots go in blocks, so that the float64 temporaries
    # follow the block, not the shot (a shot of up to SOLVE_BLOCK frames is one block).
    parts = []
    for s in range(0, max(len(inside), 1), SOLVE_BLOCK):  # one block for any short shot
        b = slice(s, s + SOLVE_BLOCK)
        loc = _slerp_frames(filled.rotations, i0[b], w[b])
        i1 = np.minimum(i0[b] + 1, T - 1)
        wb = w[b, None]
        root = (1 - wb) * filled.root_positions[i0[b]] + wb * filled.root_positions[i1]
        rot_o, tr_o, sc_o = anim_values(shot.stage, c, inside[b])
        rot_s, tr_s = retarget.from_model(loc, root, *to_skeleton_order(c, rot_o, tr_o))
        parts.append((rot_s[:, c.anim_index], tr_s[:, c.anim_index], sc_o))
        del loc, root, rot_o, tr_o, rot_s, tr_s
    rot, tr, sc_o = parts[0] if len(parts) == 1 else (np.concatenate(p) for p in zip(*parts, strict=True))
    out.update(rot=rot, tr=tr, sc=sc_o)
    return out


def rig_feet(retarget, skeleton):
    """The legs of a human character's rig (``skeleton``: its own joints), as the rig's joints
    mapped to the model's legs, in its world's Y-up centimetres (pipeline.infer.plant.Feet);
    None for a rig model's character or legs the IK cannot take (pipeline.infer.plant.feet_of)."""
    from pipeline.infer.plant import feet_of, legs_named

    roles = getattr(retarget, "roles", None)
    if roles is None:
        return None
    return feet_of(skeleton, legs_named(roles), retarget.R, retarget.s)


class OnRig:
    """Where the fill layer's trusted fill (infer.trust.trusted_fill) meets its two fills: the
    character's rig, at every frame of its fill range. The network's fill is turned back onto
    the rig; the spline fills on the rig itself at the shot's own rate, as ``--model spline``
    fills it but with the trusted fill's tangents (infer.trust.trusted_curve: a decision for
    the spline gives that curve bit for bit); the two are blended gap by gap there."""

    def __init__(self, plan: Plan, cp: CharPlan, keyed, fps: float, m: np.ndarray):
        self.plan, self.cp, self.keyed, self.fps, self.m = plan, cp, keyed, fps, m

    def model(self, fill: Motion) -> dict:
        return _onto_rig(self.plan, self.cp, self.cp.retarget, self.fps, fill, self.m)

    def spline(self, spline, cuts=()) -> dict:
        """``cuts`` name the character's jumps in model frames; the rig's spline takes the
        same key pairs in its own frames (jump_gaps at its rate)."""
        own, rate = OwnRig(self.cp.char), own_rate(self.plan.shot.tcps, self.cp.keys)
        motion, m = _keyed_motion(self.plan, self.cp, self.keyed, own, own.skeleton, rate)
        breaks = jump_gaps(self.cp, self.plan.shot.tcps, rate)
        extra = {}
        if getattr(spline, "plant", False):  # the trusted curve holds planted feet on the rig's legs
            extra["feet"] = rig_feet(self.cp.retarget, own.skeleton)
        return _onto_rig(self.plan, self.cp, own, rate, spline.fill(motion, m, breaks=breaks, **extra), m)

    def blend(self, decision, model: dict | None, spline: dict | None) -> dict:
        if model is None or spline is None:
            return spline if model is None else model
        w = gap_weights_at(decision, model["m"], model["u"])
        for s in range(0, len(w), SOLVE_BLOCK):  # float64 temporaries follow the block
            b = slice(s, s + SOLVE_BLOCK)
            model["rot"][b], model["tr"][b] = blend_arrays(
                w[b], model["rot"][b], model["tr"][b], spline["rot"][b], spline["tr"][b]
            )
        return model


def gap_table(decision, cp: CharPlan, tcps: float, fps: float) -> tuple[dict, dict]:
    """({model frame: key time code} of the keys the in-betweener was given, {(a, b): the
    decision's model weight in the gap between adjacent key frames a, b})."""
    m, keep = model_frames(cp.keys, tcps, fps)
    at = {int(f): float(t) for f, t in zip(m[keep], cp.keys[keep], strict=True)}
    frames = np.array(sorted(at), np.int64)
    if len(frames) < 2:
        return at, {}
    w = gap_weights_at(decision, frames, (frames[:-1] + frames[1:]) / 2.0)
    return at, {(int(a), int(b)): float(x) for a, b, x in zip(frames[:-1], frames[1:], w, strict=True)}


def gap_record(at: dict, weights: dict) -> list[dict]:
    """The decided model's weight over the spline in each gap between the character's keys,
    with the gap's key time codes (:func:`gap_table`): what filled which frames (the layer's
    tween:trustGaps and tween:trustGapWeights, the burn-ins)."""
    return [{"times": [at[a], at[b]], "weight": round(w, 4)} for (a, b), w in weights.items() if b - a > 1]


def library_record(library_inb, at: dict, weights: dict) -> dict:
    """What a per-gap in-betweener (a motion library) did in each gap of the character's fill:
    its record (``last_gaps``) with the key time codes of each gap, and the trusted fill's
    weight there (the gap's share of the library over the spline is the product)."""
    gaps = []
    for row in library_inb.last_gaps:
        a, b = row["frames"]
        w = weights.get((a, b), 1.0)
        gaps.append(row | {"times": [at.get(a), at.get(b)], "trust_weight": round(w, 4),
                           "share": round(w * row["weight"], 4)})  # fmt: skip
    lib = library_inb.library
    return {"name": lib.name, "hash": lib.hash, "folder": str(lib.folder), "gaps": gaps}


def _fill(plan: Plan, cp: CharPlan, inb, keyed, mask, seed: int, dna) -> dict:
    """``inb``'s fill of the character on its rig (:func:`_onto_rig`'s dict): a trusted
    in-betweener's through :func:`trusted_fill`, meeting network and spline on the rig where
    it can (:class:`OnRig`), else on the model skeleton; ``keyed``: the rig's rotations and
    translations at every key; ``mask``: the partial keys for the model (key_channels)."""
    shot, k, fps = plan.shot, cp.keys, float(cp.fps)
    extra = {} if dna is None else {"dna": dna}
    if mask is not None:  # for the keys the in-betweener is given (model_frames)
        kept = mask[model_frames(k, shot.tcps, fps)[1]]
        kept[[0, -1]] = True  # the first and last keys given stay full poses
        extra["joint_keys"] = kept
    skel = cp.retarget.skeleton if isinstance(cp.retarget, OwnRig) else inb.skeleton
    motion, m = _keyed_motion(plan, cp, keyed, cp.retarget, skel, fps)
    if not isinstance(inb, TrustedInbetweener):
        return _onto_rig(plan, cp, cp.retarget, fps, inb.fill(motion, m, seed=seed, **extra), m)
    # Partial keys and a motion DNA blend on the model skeleton, and so does a shot whose
    # rig spline, at the shot's rate, would pass the plan's bound.
    on_rig = mask is None and dna is None
    if on_rig and (k[-1] - k[0]) / shot.tcps * own_rate(shot.tcps, k) > MAX_MODEL_FRAMES:
        on_rig = False
    cuts = jump_gaps(cp, shot.tcps, fps)  # the spline's, and no network window spans one
    meet = OnRig(plan, cp, keyed, fps, m) if on_rig else None
    res = trusted_fill(inb, motion, m, seed, cuts=cuts, meet=meet, **extra)
    # Met on the model skeleton: turned back onto the rig as a whole.
    return res if meet is not None else _onto_rig(plan, cp, cp.retarget, fps, res, m)


def _trust_record(inb, cp: CharPlan, tcps: float, fps: float) -> dict | None:
    """The trusted fill's decision for the layer (None for any other in-betweener), with the
    weight of each gap (and a library's record of its gaps)."""
    if not isinstance(inb, TrustedInbetweener):
        return None
    decision = inb.last_decision
    record = decision.to_json()
    record["curve"] = getattr(inb.spline, "method", None)  # the spline's tangents (infer.trust.CURVE)
    record["plant"] = bool(getattr(inb.spline, "plant", False))  # feet the keys plant held (infer.plant)
    at, weights = gap_table(decision, cp, tcps, fps)
    record["gap_weights"] = gap_record(at, weights)
    if inb.model.capabilities.per_gap:
        record["library"] = library_record(inb.model, at, weights)
    return record


def fill_character(
    plan: Plan, cp: CharPlan, inb, seed: int, dna=None, trust: str = "auto", alternatives=()
) -> dict:
    """Times and animation-ordered rotations/translations/scales for the fill layer; ``dna``: a
    Motion of representative poses for a model that takes a motion DNA; ``trust``: how far
    the human model is trusted against the spline (pipeline.infer.trust), decided per
    character and returned under ``"trust"`` (None where nothing was decided: a rig model,
    or interpolation and the spline on the character's own rig).

    The trusted fill's spline is filled on the character's rig as ``--model spline`` fills
    it, with the trusted fill's tangents (Catmull-Rom where keys are dense: a decision for the
    spline gives that curve bit for bit), and blended with the network's fill, turned back onto the rig, gap by gap at the decided
    weights. Shots with partial keys or a motion DNA blend on the model skeleton instead.
    ``alternatives``: other in-betweeners the trusted fill probes against ``inb`` (a motion
    library's network), the better on the shot's own keys deciding."""
    shot, c = plan.shot, cp.char
    if cp.model is None and not isinstance(cp.retarget, OwnRig):
        inb = trusted(inb, trust, alternatives)
    k = cp.keys
    rot_k, tr_k, sc_k = anim_values(shot.stage, c, k)
    fps = float(cp.fps)
    # Partial keys go to models that take them (the human model); others get full keys.
    takes_partial = inb.capabilities.partial_keys and not isinstance(cp.retarget, OwnRig)
    rig_keys = rig_key_channels(cp) if takes_partial else None
    res = _fill(plan, cp, inb, (rot_k, tr_k), key_channels(cp, rig_keys), seed, dna)
    inside, rot, tr, sc_o = res["inside"], res["rot"], res["tr"], res["sc"]
    lo, hi = cp.fill_range
    if not (np.isfinite(rot).all() and np.isfinite(tr).all()):
        raise ShotError(shot.path, "the in-betweener produced non-finite values", c.anim_path)
    # Keys carry exactly the authored values (not round-tripped ones).
    pos = {float(t): i for i, t in enumerate(inside)}
    for j, t in enumerate(k):
        i = pos.get(float(t))
        if i is None:
            continue
        sc_o[i] = sc_k[j]
        # A partial key's unkeyed channels are the fill's.
        keyed = slice(None) if rig_keys is None else rig_keys[0][j, c.anim_index]
        rot[i, keyed] = rot_k[j, keyed]
        if rig_keys is None or rig_keys[1][j]:
            tr[i] = tr_k[j]

    # Outside the range every frame (and authored sample) keeps what the shot has: the
    # filled animation replaces the original's samples entirely, so they are copied.
    outside = merge_times(c.sample_times, frames_in(shot.start, shot.end))
    outside = outside[(outside < lo - TIME_EPS) | (outside > hi + TIME_EPS)]
    r2, t2, s2 = anim_values(shot.stage, c, outside)
    times = np.concatenate([inside, outside])
    order = np.argsort(times, kind="stable")
    return {
        "trust": _trust_record(inb, cp, shot.tcps, fps),
        "times": times[order],
        "rot": np.concatenate([rot, r2])[order],
        "trans": np.concatenate([tr, t2])[order],
        "scale": np.concatenate([sc_o, s2])[order],
        "keys": k,
        "inside": inside,
    }
