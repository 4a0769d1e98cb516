"""Never worse than the animator's curves: per shot, how far to trust the network over the spline.

The shipped network is far ahead of interpolation on its own benchmark, and behind it on other
actors or on rigs posed differently from the capture (README, issue 19). A studio's shot says
which case it is only through its keys, so the evidence comes from the keys alone: **probes**.
A probe leaves a few interior keys out, fills the rest of a local window around them with the
model and with the spline, and measures both against the left-out keys (global joint
positions by forward kinematics on the model skeleton, in cm). The keys' own poses are the
ground truth, so a model that does not know this character shows it there.

Probes (:func:`probe_plan`, at most :data:`MAX_PROBES` a shot, each a local window):

- **gap probes**: beside a gap of the shot, the keys nearest to it are left out until the gap
  grows by at least :data:`MIN_GAP` frames. Where keys are sparse (blocking every few frames)
  that is one key (leave-one-out); beside a run of consecutive keys (the protocol's 10 context
  frames) it is a run of keys, and the probe is then the shot's own task with a longer gap.
- **run probes**: inside a run of consecutive keys, a hole of :data:`MIN_GAP` keys with at
  least two keys of the run kept on each side, and the widest hole (the run's two end keys
  kept), which asks the model for a motion the keys barely constrain.

Decision (:func:`decide`), **per gap length**: per probe the log-ratio
``log((e_spline + ε) / (e_model + ε))`` (ε = :data:`EPS_CM`, so sub-millimetre probes do not
dominate), averaged (each probe at its :func:`alias_weights`: one on keys that repeat a pose
while the character travels across its hole counts less), then shrunk toward the model's end
of the band by :data:`PRIOR_PROBES` pseudo-probes (few probes cannot flip a good model). For a
gap of L frames the weight of the model is ``w = clip((score − t(L)) / BAND + 1/2, 0, 1)``
with the threshold t(L) of :func:`threshold_for`: 0 for gaps no longer than the probes' holes
(there the probes measure the gap's own task, so equal errors give w = 1/2), falling to
:data:`THRESHOLD` for gaps of :data:`LONG_GAP` frames and more (the network's lead over the
spline grows with the gap, so probes on short holes understate it there). A shot whose gaps all get 1 is ``"model"``, all 0
``"spline"``, otherwise ``"blend"``: each gap's frames are spline + w·(model − spline), the
root position linearly and every joint's local rotation by SLERP (:func:`apply`). Keys stay
bitwise exact.

:class:`TrustedInbetweener` wraps a model in the same ``fill`` interface and keeps
``last_decision`` (a JSON-ready :class:`TrustDecision`) for the fill layer to record;
:func:`trusted_fill` is the one trusted fill (decide, cut, fill, blend), on the model skeleton
or, from the fill layer, on the character's rig; :func:`trusted_fill_windows` its steps
batched over the benchmark's windows.
How the constants were chosen, and what they give on the benchmark: docs/trust.md.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from pipeline.infer.api import fill_windows
from pipeline.infer.novelty import familiarity, novelty_cm
from pipeline.motion.clip import Motion
from pipeline.motion.fk import fk
from pipeline.motion.rotations import slerp_pairs

TRUST_MODES = ("auto", "model", "spline")
CHOICES = ("model", "spline", "blend")
#: The shortest gap a probe opens, in frames (and how much a gap probe lengthens a gap).
MIN_GAP = 5
#: At most this many probes a shot (each one local window of the model and of the spline).
MAX_PROBES = 8
#: Keys of a run kept on each side of a run probe's hole.
RUN_SIDE = 2
#: Added to both probe errors (cm) before their ratio.
EPS_CM = 0.2
#: Score (mean log error ratio spline / model) at which the weight is one half, for gaps of
#: LONG_GAP frames and more; for gaps up to MIN_GAP frames (the probes' own holes) it is 0.
THRESHOLD = -0.3
#: The gap length (frames) from which the threshold is THRESHOLD (log-linear from MIN_GAP).
LONG_GAP = 3 * MIN_GAP
#: Score range over which the weight goes from 0 to 1.
BAND = 0.4
#: Pseudo-probes at the model's end of the band (w = 1) the probes' mean is shrunk toward.
PRIOR_PROBES = 1.0
#: A probe counts in full when the spline misses its left-out keys by at least this share of
#: the root's travel across the hole, and in proportion below it (an aliased probe: below).
ALIAS = 0.3
#: Probe holes shorter than this many frames (0.4 s at the models' 30 fps) count in full:
#: no human gait cycle (two steps, a sprint's included) is shorter, so no key there repeats.
CYCLE_FRAMES = 12
#: The tangents of the trusted fill's curve (:func:`trusted_curve`).
CURVE = "adaptive"
#: Windows per model call when probing many shots at once.
BATCH = 128


@dataclass(frozen=True)
class Probe:
    """One probe: the window of frames ``lo..hi`` the two methods fill, from the keys ``kept``,
    scored at the keys ``left_out`` (absolute frame numbers); ``gap`` the frames between the
    kept keys around the hole; ``kind`` "gap" or "run"."""

    lo: int
    hi: int
    kept: tuple[int, ...]
    left_out: tuple[int, ...]
    gap: int
    kind: str

    def describe(self) -> dict:
        return {
            "kind": self.kind,
            "frames": [self.lo, self.hi],
            "left_out": [self.left_out[0], self.left_out[-1]],
            "n_left_out": len(self.left_out),
            "gap": self.gap,
        }


@dataclass
class TrustDecision:
    """How one character's fill was decided. ``weight``: the model's share (1: the model's
    fill, 0: the spline's), over the shot's gap frames; ``model_error_cm`` /
    ``spline_error_cm``: the mean joint-position error of each at the probes' left-out keys
    (None without probes); ``score``: the probes' mean log error ratio (spline / model);
    ``probes``: one dict per probe (its window, left-out keys and both errors); ``gaps``: one
    dict per gap length of the shot (``length``, ``count``, the probes' shortest hole
    ``probe_hole``, ``threshold``, shrunk ``score``, ``weight``), the weight of every gap of
    that length; ``novelty_cm`` / ``familiarity``: how far the keys are from the model's pose
    bank and what that made of it (None without a bank; ``familiar_credit`` False: the model
    has none, so familiarity counted 0, docs/trust.md); ``cuts``: gaps ([first, last]
    key frame) the body teleports across, which the spline fills whatever their length's
    weight (:meth:`with_cuts`); ``source``: the in-betweener decided on, where there were
    several (``candidates``: each one's name, hash, probe score and error); ``reason``: one
    line for people."""

    choice: str
    weight: float
    model_error_cm: float | None
    spline_error_cm: float | None
    probes: list[dict] = field(default_factory=list)
    reason: str = ""
    score: float | None = None
    trust: str = "auto"
    gaps: list[dict] = field(default_factory=list)
    novelty_cm: float | None = None
    familiarity: float | None = None
    cuts: list[list[int]] = field(default_factory=list)
    source: str | None = None
    candidates: list[dict] = field(default_factory=list)
    familiar_credit: bool = True

    def to_json(self) -> dict:
        """Plain JSON types only (what a layer attribute or log line can carry)."""
        return asdict(self)

    def with_cuts(self, pairs, keys) -> TrustDecision:
        """This decision with the gaps between the key frames of ``pairs`` ((a, b), adjacent
        keys of ``keys``) given to the spline whatever their length's weight: cuts, keys the
        body teleports between (pipeline.fill.jumps), where what the network learned of motion
        says nothing and the animator's curve is the least surprise. ``weight`` and ``choice``
        follow (over the gap frames of ``keys``); pairs that are no gap of ``keys`` are ignored."""
        k = _unique_keys(keys)
        gaps = {(int(a), int(b)) for a, b in zip(k[:-1], k[1:], strict=True) if b - a > 1}
        own = sorted({(int(a), int(b)) for a, b in pairs} & gaps)
        if not own:
            return self
        merged = sorted({*map(tuple, self.cuts), *own})
        new = replace(self, cuts=[list(g) for g in merged])
        lengths = np.diff(k) - 1
        w = _per_gap(new, k)[lengths > 0]
        n = lengths[lengths > 0].astype(np.float64)
        new.weight = round(float(np.dot(n, w) / n.sum()), 6)
        new.choice = "model" if w.min() >= 1.0 else "spline" if w.max() <= 0.0 else "blend"
        new.reason += f"; {len(own)} gap(s) the body teleports across: the spline"
        return new

    def frame_weights(self, keys, n_frames: int) -> np.ndarray:
        """The model's weight per frame (n_frames,) of a shot keyed at ``keys`` (the full keys
        the decision was made on): each gap's frames its length's weight, every other frame 1
        (keys and held frames, where both fills agree). Every frame ``weight`` where the
        decision has no per-gap weights (overrides, no probes)."""
        if not self.gaps and not self.cuts:
            return np.full(n_frames, float(self.weight))
        return gap_weights_at(self, keys, np.arange(n_frames))


def _per_gap(decision: TrustDecision, keys: np.ndarray) -> np.ndarray:
    """The model's weight in each gap of the unique ``keys``: its length's (``weight`` where
    the decision has none), 0 across a cut, 1 between keys on adjacent frames."""
    lengths = np.diff(keys) - 1
    by_length = {int(g["length"]): float(g["weight"]) for g in decision.gaps}
    per_gap = np.array([by_length.get(int(n), decision.weight) if n > 0 else 1.0 for n in lengths])
    for a, b in decision.cuts:
        per_gap[(keys[:-1] == a) & (keys[1:] == b)] = 0.0
    return per_gap


def gap_weights_at(decision: TrustDecision, keys, frames) -> np.ndarray:
    """The model's weight at (fractional) model frames ``frames`` of a shot keyed at ``keys``:
    the weight of the gap each falls in (1 at a key and outside the keys)."""
    keys = _unique_keys(keys)
    u = np.asarray(frames, np.float64)
    at_key = np.isin(u, keys) | (u <= keys[0]) | (u >= keys[-1])
    if not decision.gaps and not decision.cuts:
        return np.where(at_key, 1.0, float(decision.weight))
    # One weight per gap, looked up per frame; between keys on adjacent frames (no frame
    # to fill) 1, as frame_weights gives every frame outside a gap.
    j = np.clip(np.searchsorted(keys, u, side="right") - 1, 0, len(keys) - 2)
    return np.where(at_key, 1.0, _per_gap(decision, keys)[j])


def _unique_keys(keys) -> np.ndarray:
    return np.unique(np.asarray(keys, np.int64))


def _runs(keys: np.ndarray) -> list[tuple[int, int]]:
    """Index ranges [a, b] of maximal runs of consecutive-frame keys (of two keys or more)."""
    out, a = [], 0
    for i in range(1, len(keys) + 1):
        if i == len(keys) or keys[i] != keys[i - 1] + 1:
            if i - 1 > a:
                out.append((a, i - 1))
            a = i
    return out


def _make_probe(keys: np.ndarray, i: int, j: int, kind: str) -> Probe:
    """The probe leaving keys[i..j] (interior indices) out, in a window reaching as far as the
    hole's gap on each side (but at least to the kept keys around the hole)."""
    left, right = int(keys[i - 1]), int(keys[j + 1])
    gap = right - left - 1
    reach = max(gap, MIN_GAP)
    # the window's keys found by bisection (keys are sorted and unique): a scan of every key
    # for every probe made a shot's probes cost the square of its keys (26 s at 8,000 keys)
    lo, hi = np.searchsorted(keys, left - reach, "left"), np.searchsorted(keys, right + reach, "right")
    kept = [int(k) for k in keys[lo:i]] + [int(k) for k in keys[j + 1 : hi]]
    return Probe(kept[0], kept[-1], tuple(kept), tuple(int(k) for k in keys[i : j + 1]), gap, kind)


def _spread(items: list, n: int) -> list:
    """At most ``n`` of ``items``, evenly spaced, in order."""
    if len(items) <= n:
        return list(items)
    idx = np.unique(np.round(np.linspace(0, len(items) - 1, n)).astype(int))
    return [items[i] for i in idx]


def probe_plan(keys, max_probes: int = MAX_PROBES) -> list[Probe]:
    """The probes of a shot keyed at ``keys`` (frame numbers): see the module docstring.
    The first and last keys are never left out; fewer than three keys give no probe."""
    keys = _unique_keys(keys)
    n = len(keys)
    if n < 3 or max_probes <= 0:
        return []
    gap_probes: dict[tuple[int, int], Probe] = {}
    for g in range(n - 1):
        length = int(keys[g + 1] - keys[g] - 1)
        if length <= 0:
            continue
        # Left side: leave keys[g - r + 1 .. g] out; right side: keys[g + 1 .. g + r].
        for r in range(1, g + 1):
            if keys[g + 1] - keys[g - r] - 1 >= length + MIN_GAP or r == g:
                gap_probes.setdefault((g - r + 1, g), _make_probe(keys, g - r + 1, g, "gap"))
                break
        for r in range(1, n - 2 - g + 1):
            if keys[g + 1 + r] - keys[g] - 1 >= length + MIN_GAP or r == n - 2 - g:
                gap_probes.setdefault((g + 1, g + r), _make_probe(keys, g + 1, g + r, "gap"))
                break
    run_probes: list[Probe] = []
    for a, b in _runs(keys):
        size = b - a + 1
        # Run ends that are the shot's ends stay keys: a hole needs a kept key on both sides.
        lo_i, hi_i = max(a + RUN_SIDE, 1), min(b - RUN_SIDE, n - 2)
        offsets = list(range(lo_i, hi_i - MIN_GAP + 2))
        for s in _spread(offsets, 2):
            run_probes.append(_make_probe(keys, s, s + MIN_GAP - 1, "run"))
        wa, wb = max(a + 1, 1), min(b - 1, n - 2)
        if size >= MIN_GAP + 2 and wb - wa + 1 > MIN_GAP:
            run_probes.append(_make_probe(keys, wa, wb, "run"))
    gaps = sorted(gap_probes.values(), key=lambda p: p.left_out[0])
    n_gap = min(len(gaps), max(max_probes - len(run_probes), (max_probes + 1) // 2))
    chosen = _spread(gaps, n_gap)
    chosen += _spread(run_probes, max_probes - len(chosen))
    return sorted(chosen, key=lambda p: (p.left_out[0], p.left_out[-1]))


# -- filling probes ----------------------------------------------------------------------------


def _cm_per_unit(skeleton) -> float:
    return 100.0 * float(getattr(skeleton, "meters_per_unit", 0.01))


def _errors_cm(skeleton, rot, root, true_rot, true_root) -> np.ndarray:
    """(N,) mean global joint-position error over frames and joints, in cm."""
    to_cm = _cm_per_unit(skeleton)
    _, a = fk(rot, root, skeleton.parents, skeleton.offsets)
    _, b = fk(true_rot, true_root, skeleton.parents, skeleton.offsets)
    return np.linalg.norm(np.asarray(a, np.float64) - b, axis=-1).mean(axis=(1, 2)) * to_cm


def run_probes(model, spline, rots, roots, probes: list[Probe], skeleton=None, cache: dict | None = None):
    """Model and spline errors (cm), each (N, P), of ``probes`` on N shots sharing their keys.

    ``cache`` (a dict kept by the caller) reuses a probe's errors for a later call whose
    probe covers the same frames and keys of the same shots (the benchmark's transition
    lengths share their context probes); the caller vouches that those frames are the same.
    """
    skel = skeleton or model.skeleton
    rots, roots = np.asarray(rots), np.asarray(roots)
    N = len(rots)
    em = np.zeros((N, len(probes)))
    es = np.zeros((N, len(probes)))
    for c, p in enumerate(probes):
        tag = (p.lo, p.hi, p.kept, p.left_out)
        if cache is not None and tag in cache:
            em[:, c], es[:, c] = cache[tag]
            continue
        win = slice(p.lo, p.hi + 1)
        w_rot, w_root = rots[:, win], roots[:, win]
        kept = np.asarray(p.kept, np.int64) - p.lo
        out = np.asarray(p.left_out, np.int64) - p.lo
        true_r, true_p = w_rot[:, out], w_root[:, out]
        m_r, m_p = fill_windows(model, w_rot, w_root, kept, BATCH, skel)
        s_r, s_p = fill_windows(spline, w_rot, w_root, kept, BATCH, skel)
        em[:, c] = _errors_cm(skel, m_r[:, out], m_p[:, out], true_r, true_p)
        es[:, c] = _errors_cm(skel, s_r[:, out], s_p[:, out], true_r, true_p)
        if cache is not None:
            cache[tag] = (em[:, c].copy(), es[:, c].copy())
    return em, es


# -- the decision ------------------------------------------------------------------------------


def threshold_for(gap: int, hole: int = MIN_GAP) -> float:
    """The score at which a gap of ``gap`` frames gets weight one half, for probes whose
    shortest hole is ``hole`` frames: 0 up to ``hole`` (the probes asked the model for a gap
    at least this long, so their score is the gap's own, or harder), THRESHOLD from
    ``hole`` · LONG_GAP / MIN_GAP on (the network's lead over the spline grows with the gap,
    so probes on shorter holes understate it there), log-linear between. A shot with a run of
    dense keys has MIN_GAP holes; a blocked shot's leave-one-out probes have holes as long as
    two of its gaps and a key."""
    hole = max(int(hole), MIN_GAP)
    if gap <= hole:
        return 0.0
    if gap >= hole * LONG_GAP / MIN_GAP:
        return THRESHOLD
    return float(THRESHOLD * np.log(gap / hole) / np.log(LONG_GAP / MIN_GAP))


def weight_of(score: float, threshold: float = THRESHOLD) -> float:
    """The model's weight for a (shrunk) score, against a gap's threshold."""
    return float(np.clip((score - threshold) / BAND + 0.5, 0.0, 1.0))


def shrunk_score(
    log_ratios: np.ndarray, threshold: float = THRESHOLD, familiar: float = 1.0, weights=None
) -> float:
    """Mean of the probes' log ratios (each counted at its ``weights``, 1 by default), shrunk
    toward the model's end of the band for a shot as familiar as the training data, toward the
    middle (w = 1/2) for an unseen one: few probes cannot flip a good model on the motion it
    knows, and elsewhere it has no such credit."""
    prior = threshold + 0.5 * BAND * familiar
    lr = np.asarray(log_ratios, np.float64)
    wt = np.ones_like(lr) if weights is None else np.asarray(weights, np.float64)
    return float((np.dot(wt, lr) + PRIOR_PROBES * prior) / (wt.sum() + PRIOR_PROBES))


def alias_weights(spline_cm: np.ndarray, travel_cm: np.ndarray, holes=None) -> np.ndarray:
    """How much each probe counts: 1 where the spline misses the left-out keys by at least
    ALIAS × the root's travel across the hole, in proportion below. A character that travels
    far across a hole while the spline, which slides between the kept keys, still lands on
    the left-out key repeats one pose at the keys: a cycle keyed at its period (a walk keyed
    every 30 frames, a step a second). Such a probe rewards the spline for landing on a
    repeated pose, while between the shot's own keys the spline glides; it says little about
    the gaps. A probe whose hole the character does not travel across counts in full, as
    does one whose hole (``holes``, frames) is shorter than a gait cycle (CYCLE_FRAMES), and
    one the spline hits within EPS_CM (falling to none at twice that): a pose held
    exactly while the root moves is the animator's own glide (copied keys), where the spline
    is right between the keys too; no capture repeats a pose that closely."""
    reach = ALIAS * np.asarray(travel_cm, np.float64)
    es = np.asarray(spline_cm, np.float64)
    cycle = np.clip(np.divide(es, reach, out=np.ones_like(es), where=reach > 0), 0.0, 1.0)
    held = np.clip((2.0 * EPS_CM - es) / EPS_CM, 0.0, 1.0)
    short = np.zeros_like(es) if holes is None else (np.asarray(holes) < CYCLE_FRAMES).astype(np.float64)
    return np.maximum(np.maximum(cycle, held), short)


def gap_lengths(keys) -> dict[int, int]:
    """{gap length in frames: how many gaps of the shot have it}, in order of length."""
    keys = _unique_keys(keys)
    lengths = np.diff(keys) - 1
    lengths = lengths[lengths > 0]
    values, counts = np.unique(lengths, return_counts=True)
    return {int(v): int(c) for v, c in zip(values, counts, strict=True)}


def gap_threshold(length: int, hole: int, familiar: float = 1.0) -> float:
    """A gap's threshold for a shot of the given familiarity (:mod:`pipeline.infer.novelty`):
    a familiar shot's long gaps lean toward the network from the shortest probe hole the
    prior was measured on (MIN_GAP: the network's lead grows with the gap on its own data); an
    unseen shot's from the probes' own shortest hole (no lead assumed beyond what they show)."""
    return float(familiar * threshold_for(length) + (1.0 - familiar) * threshold_for(length, hole))


def _gap_weights(
    lr: np.ndarray, keys, hole: int = MIN_GAP, familiar: float = 1.0, weights=None
) -> list[dict]:
    rows = []
    for length, count in gap_lengths(keys).items():
        t = gap_threshold(length, hole, familiar)
        score = shrunk_score(lr, t, familiar, weights)
        rows.append(
            {
                "length": length,
                "count": count,
                "probe_hole": int(max(hole, MIN_GAP)),
                "threshold": round(t, 6),
                "score": round(score, 6),
                "weight": round(weight_of(score, t), 6),
            }
        )
    return rows


def _describe_weights(gaps: list[dict]) -> str:
    if not gaps:
        return "no frame between the keys: the model, unchanged"
    if len({g["weight"] for g in gaps}) == 1:
        w = gaps[0]["weight"]
        return "the model" if w >= 1.0 else "the spline" if w <= 0.0 else f"blend w={w:.2f}"
    parts = [f"{g['length']}-frame gaps w={g['weight']:.2f}" for g in gaps[:4]]
    return "per gap length: " + ", ".join(parts) + (", …" if len(gaps) > 4 else "")


#: A probe error (cm) standing for a fill that is not finite: far beyond any pose's miss.
LOST_CM = 1e6
#: A decision without probes.
UNCHECKED = "no probe possible (fewer than three keys): the model, unchecked"
#: What a decision's reason adds for a model without the familiar credit (keyed by the credit).
_NO_CREDIT = {True: "", False: "; no familiar credit (model.json): the probes alone decide"}


def _decision(
    em: np.ndarray,
    es: np.ndarray,
    probes: list[Probe],
    keys=(),
    novelty: float | None = None,
    travel: np.ndarray | None = None,
    credit: bool = True,
) -> TrustDecision:
    if not probes:
        return TrustDecision("model", 1.0, None, None, [], UNCHECKED, None)
    # A model whose probe fill is not finite lost that probe (the spline fills, never NaN).
    em = np.where(np.isfinite(em), em, LOST_CM)
    lr = np.log((es + EPS_CM) / (em + EPS_CM))
    holes = [p.gap for p in probes]
    counted = np.ones_like(lr) if travel is None else alias_weights(es, travel, holes)
    mean_lr = float(np.mean(lr))
    familiar = familiarity(novelty) if credit else 0.0
    gaps = _gap_weights(lr, keys, min(holes), familiar, counted)
    frames = np.array([g["length"] * g["count"] for g in gaps], np.float64)
    ws = np.array([g["weight"] for g in gaps], np.float64)
    w = float(np.dot(frames, ws) / frames.sum()) if len(gaps) else 1.0
    choice = "model" if ws.min(initial=1.0) >= 1.0 else "spline" if ws.max(initial=0.0) <= 0.0 else "blend"
    me, se = float(np.mean(em)), float(np.mean(es))
    rows = [
        {
            **p.describe(),
            "model_cm": round(float(a), 4),
            "spline_cm": round(float(b), 4),
            "counted": round(float(c), 4),
        }
        for p, a, b, c in zip(probes, em, es, counted, strict=True)
    ]
    better = int(np.sum(em < es))
    seen = "" if novelty is None else f"; keys {novelty:.1f} cm from the training poses"
    aliased = int(np.sum(counted < 0.5))
    cyc = f"; {aliased} on keys repeating one pose (counted less)" if aliased else ""
    reason = (
        f"{len(probes)} probe(s) from the keys: model {me:.2f} cm, spline {se:.2f} cm at the "
        f"left-out keys (model better on {better}){cyc}{seen}{_NO_CREDIT[credit]}; score {mean_lr:+.2f} → "
        + _describe_weights(gaps)
    )
    return TrustDecision(
        choice,
        round(w, 6),
        round(me, 4),
        round(se, 4),
        rows,
        reason,
        round(mean_lr, 6),
        gaps=gaps,
        novelty_cm=None if novelty is None else round(float(novelty), 4),
        familiarity=None if novelty is None and credit else round(familiar, 6),
        familiar_credit=credit,
    )


def across_cuts(probes: list[Probe], cuts) -> list[Probe]:
    """The probes whose window holds none of the ``cuts`` ((a, b) key frames the body
    teleports between): a probe across one measures the teleport, not the motion."""
    return [p for p in probes if not any(a < p.hi and b > p.lo for a, b in cuts)]


def decide_batch(
    model, spline, rots, roots, keys, skeleton=None, cache: dict | None = None, cuts=()
) -> list[TrustDecision]:
    """:func:`decide` for N shots sharing their keys: rotations (N, T, J, 4), roots (N, T, 3)
    on the model skeleton (only the key frames are read). One model call per probe. No probe
    spans one of the ``cuts``."""
    planned = probe_plan(keys)
    probes = across_cuts(planned, cuts)
    if not probes:
        d = _decision(np.zeros(0), np.zeros(0), [])
        if planned:
            d.reason = "no probe possible away from the cuts: the model, unchecked"
        return [replace(d) for _ in range(len(rots))]
    em, es = run_probes(model, spline, rots, roots, probes, skeleton, cache)
    bank = model.pose_bank if model.capabilities.novelty else None
    novelty = [None] * len(rots)
    if bank is not None:
        k = _unique_keys(keys)
        novelty = novelty_cm(
            np.asarray(rots)[:, k], np.asarray(roots)[:, k], bank, skeleton or model.skeleton
        )
    travel = probe_travel_cm(np.asarray(roots), probes, skeleton or model.skeleton)
    credit = model.capabilities.familiar_credit  # False: a studio's fine-tune (docs/trust.md)
    return [_decision(em[i], es[i], probes, keys, novelty[i], travel[i], credit) for i in range(len(rots))]


def probe_travel_cm(roots: np.ndarray, probes: list[Probe], skeleton) -> np.ndarray:
    """(N, P) how far the root travels over the ground (the model skeleton is Y up) between
    the kept keys around each probe's hole, in cm."""
    to_cm = _cm_per_unit(skeleton)
    out = np.zeros((len(roots), len(probes)))
    for c, p in enumerate(probes):
        a = max(k for k in p.kept if k < p.left_out[0])
        b = min(k for k in p.kept if k > p.left_out[-1])
        step = np.asarray(roots[:, b], np.float64) - roots[:, a]
        out[:, c] = np.hypot(step[:, 0], step[:, 2]) * to_cm
    return out


def decide(model, spline, motion: Motion, keys, cuts=()) -> TrustDecision:
    """How far to trust ``model`` over ``spline`` on this shot, from its ``keys`` alone; the
    ``cuts`` (key frames the body teleports between) go to the spline, and no probe spans one."""
    d = decide_batch(
        model, spline, motion.rotations[None], motion.root_positions[None], keys, motion.skeleton, cuts=cuts
    )[0]
    return d.with_cuts(cuts, keys)


def fill_across_cuts(model, motion: Motion, keys, cuts, joint_keys=None, **kw) -> Motion:
    """``model``'s fill of ``motion`` from ``keys``, each stretch of keys between the ``cuts``
    ((a, b) adjacent key frames the body teleports between) filled on its own, so no window of
    the network spans a teleport; frames inside a cut keep ``motion``'s values (the decision
    gives them to the spline). Without cuts, or for a model that fills each gap on its own
    (``capabilities.per_gap``), ``model.fill`` as it is."""
    keys = np.asarray(keys, np.int64)
    cuts = sorted((int(a), int(b)) for a, b in cuts if a in keys and b in keys)
    if not cuts or model.capabilities.per_gap:  # no window of a per-gap fill spans a key
        extra = kw if joint_keys is None else {**kw, "joint_keys": joint_keys}
        return model.fill(motion, keys, **extra)
    rot, root = motion.rotations.copy(), motion.root_positions.copy()
    edges = [int(keys.min()), *(x for c in cuts for x in c), int(keys.max())]
    for lo, hi in zip(edges[0::2], edges[1::2], strict=True):
        inside = (keys >= lo) & (keys <= hi)
        if len(np.unique(keys[inside])) < 2:
            continue  # a lone key between two cuts (or at an end): nothing to fill
        extra = dict(kw) if joint_keys is None else {**kw, "joint_keys": np.asarray(joint_keys)[inside]}
        part = model.fill(motion.slice(lo, hi + 1), keys[inside] - lo, **extra)
        rot[lo : hi + 1], root[lo : hi + 1] = part.rotations, part.root_positions
    return replace(motion, rotations=rot, root_positions=root)


# -- applying it -------------------------------------------------------------------------------


def blend_arrays(weight, m_rot, m_root, s_rot, s_root) -> tuple[np.ndarray, np.ndarray]:
    """spline + w·(model − spline): root linearly, local rotations by SLERP; ``weight`` a
    scalar or one per leading index (e.g. (N,) for (N, T, J, 4) windows, (T,) per frame).
    Where the two fills are bitwise equal (keys, held frames), or w is 1 or 0, the result is
    that fill's value, bitwise."""
    m_rot, s_rot = np.asarray(m_rot), np.asarray(s_rot)
    m_root, s_root = np.asarray(m_root), np.asarray(s_root)
    w = np.asarray(weight, np.float64)
    w_rot = np.broadcast_to(w.reshape(w.shape + (1,) * (m_rot.ndim - 1 - w.ndim)), m_rot.shape[:-1])
    w_root = w.reshape(w.shape + (1,) * (m_root.ndim - w.ndim))
    rot = slerp_pairs(s_rot, m_rot, w_rot).astype(s_rot.dtype)
    root = (s_root + w_root * (np.asarray(m_root, np.float64) - s_root)).astype(s_root.dtype)
    # w = 1 (0) is the model's (spline's) value bitwise: SLERP at an end may give the other
    # sign of the same quaternion, and s + 1·(m − s) is not m in floating point.
    same_r = (m_rot == s_rot).all(-1, keepdims=True)
    rot = np.where(w_rot[..., None] >= 1.0, m_rot, np.where(same_r | (w_rot[..., None] <= 0.0), s_rot, rot))
    w_p = np.broadcast_to(w_root, m_root.shape)
    root = np.where(w_p >= 1.0, m_root, np.where((m_root == s_root) | (w_p <= 0.0), s_root, root))
    return rot, root


def apply(
    decision: TrustDecision, model_fill: Motion | None, spline_fill: Motion | None, keys=None
) -> Motion:
    """The decided fill: the model's, the spline's, or their blend (:func:`blend_arrays`), each
    gap at its length's weight where ``keys`` (the full keys decided on) are given, else at
    the decision's one ``weight``. The fill not needed may be None (``"model"`` needs no
    spline fill, ``"spline"`` no model fill). Keys are bitwise those of the inputs."""
    if decision.choice not in CHOICES:
        raise ValueError(f"unknown trust choice {decision.choice!r} (one of {', '.join(CHOICES)})")
    if decision.choice == "model" or (decision.choice == "blend" and decision.weight >= 1.0):
        if model_fill is None:
            raise ValueError("the decision takes the model's fill, and none was given")
        return model_fill
    if spline_fill is None:
        raise ValueError("the decision takes the spline's fill, and none was given")
    if decision.choice == "spline" or decision.weight <= 0.0:
        return spline_fill
    if model_fill is None:
        raise ValueError("a blend needs both fills")
    w = decision.weight if keys is None else decision.frame_weights(keys, len(spline_fill.rotations))
    rot, root = blend_arrays(
        w,
        model_fill.rotations,
        model_fill.root_positions,
        spline_fill.rotations,
        spline_fill.root_positions,
    )
    return replace(spline_fill, rotations=rot, root_positions=root)


def trusted_curve(skeleton=None):
    """The curve the trusted fill checks the model against and falls back on: the spline
    through the keys with :data:`CURVE` tangents (``pipeline.infer.spline``), not the DCC
    default's clamped ones the benches compare with (``--model spline``): on dense keys it
    is 3-5 % closer to held-out motion (4 % further on motion that ends in holds), and on
    sparse ones it is that spline; and a foot the keys plant stays planted between them
    (pipeline.infer.plant)."""
    from pipeline.infer.spline import SplineInbetweener

    return SplineInbetweener(skeleton, method=CURVE, plant=True)


def spline_fill(spline, motion: Motion, keys, joint_keys=None, breaks=()) -> Motion:
    """The spline's fill of a shot; with partial keys (``joint_keys``, (K, J + 1)) through the
    full keys, then each partial key's keyed channels matched as the model matches them
    (:func:`pipeline.infer.post.match_keys`), so both fills hold the same keys. ``breaks``:
    the keys' cuts, (a, b) key frames, to a spline that takes them."""
    keys = np.asarray(keys, np.int64)
    extra = {"breaks": [tuple(c) for c in breaks]} if len(breaks) else {}
    if joint_keys is None or np.asarray(joint_keys, bool).all():
        return spline.fill(motion, np.unique(keys), **extra)
    from pipeline.infer.post import match_keys

    mask = np.asarray(joint_keys, bool)
    out = spline.fill(motion, keys[mask.all(axis=1)], **extra)
    q, r = match_keys(
        out.rotations[None],
        out.root_positions[None],
        motion.rotations[keys][None],
        motion.root_positions[keys][None],
        keys,
        mask,
    )
    return replace(out, rotations=np.asarray(q[0]), root_positions=np.asarray(r[0]))


class TrustedInbetweener:
    """A model that checks itself against the spline on every shot before filling it.

    ``trust``: ``"auto"`` (probe, then the model, the spline or a blend), ``"model"`` or
    ``"spline"`` (no probes: that one's fill). Same ``fill`` interface, skeleton, frame rate,
    name and hash as ``model``; ``last_decision`` is the :class:`TrustDecision` of the latest
    ``fill`` or ``decide`` (``.to_json()`` for a layer attribute). The fill layer calls
    :func:`trusted_fill` itself, to blend on the character's rig (pipeline.fill.solve).

    ``alternatives``: other in-betweeners on the same skeleton and rate (a motion library's
    network). With ``"auto"`` each is probed on the shot's own keys as ``model`` is, and the
    one whose probes beat the spline by most is decided on: ``model`` then names it until the
    next decision (the first, ``primary``, on a tie or without probes).
    """

    def __init__(self, model, spline=None, trust: str = "auto", alternatives=()):
        if trust not in TRUST_MODES:
            raise ValueError(f"unknown trust {trust!r} (one of {', '.join(TRUST_MODES)})")
        if spline is None:
            spline = trusted_curve(model.skeleton)
        self.model, self.spline, self.trust = model, spline, trust
        self.primary = model
        self.alternatives = tuple(
            a
            for a in alternatives
            if not a.capabilities.any_rig and a.skeleton.names == model.skeleton.names and a.fps == model.fps
        )
        self.name = model.name
        self.model_hash = model.model_hash
        self.fps = model.fps
        self.skeleton = model.skeleton
        # One shot at a time (no fill_batch), on the model's skeleton.
        self.capabilities = replace(model.capabilities, batch=False, any_rig=False)
        self.last_decision: TrustDecision | None = None

    @property
    def pose_bank(self):
        """The wrapped model's pose bank (with ``capabilities.novelty``)."""
        return self.model.pose_bank if self.model.capabilities.novelty else None

    def decide(self, motion: Motion, keys, cuts=()) -> TrustDecision:
        """The decision for a shot keyed at ``keys`` (its full keys): probed with ``"auto"``,
        the override otherwise; kept as ``last_decision``. ``cuts``: (a, b) key frames
        the body teleports between, given to the spline with ``"auto"``
        (:meth:`TrustDecision.with_cuts`)."""
        self.model = self.primary
        if self.trust == "model":
            d = TrustDecision(
                "model", 1.0, None, None, [], "trust=model: the model, unchecked", None, "model"
            )
        elif self.trust == "spline":
            d = TrustDecision("spline", 0.0, None, None, [], "trust=spline: the spline", None, "spline")
        else:
            d = decide(self.model, self.spline, motion, keys, cuts)
            if self.alternatives and probes_beside(self.primary, d):
                d = self._choose(d, motion, keys, cuts)
            elif self.alternatives:
                d.reason += "; keys as familiar as its training data: nothing probed beside it"
        self.last_decision = d
        return d

    def _choose(self, first: TrustDecision, motion: Motion, keys, cuts) -> TrustDecision:
        """Of the primary's decision and each alternative's, the one whose probes beat the
        spline by most (score: mean log error ratio spline / model), an alternative only by
        more than the primary's ``capabilities.probe_margin``; ``model`` follows."""
        options = [(self.primary, first)] + [
            (a, decide(a, self.spline, motion, keys, cuts)) for a in self.alternatives
        ]
        rows = [{"name": m.name, "hash": m.model_hash, "score": d.score, "model_error_cm": d.model_error_cm}
                for m, d in options]  # fmt: skip
        model, d = options[pick([d.score for _, d in options], *choice_rule(self.primary, self.alternatives))]
        self.model = model
        others = ", ".join(
            f"{r['name']} {r['score']:+.2f}"
            for r in rows
            if r["score"] is not None and r["name"] != model.name
        )
        d = replace(d, source=model.name, candidates=rows)
        if others:
            d.reason += f"; {model.name} chosen by the probes (score {d.score:+.2f}; {others})"
        return d

    def fill(self, motion: Motion, keys, seed: int = 0, joint_keys=None, dna=None, cuts=()) -> Motion:
        """:func:`trusted_fill` on the model skeleton."""
        return trusted_fill(self, motion, keys, seed, joint_keys, dna, cuts)


class OnSkeleton:
    """Where :func:`trusted_fill` meets its two fills by default: the model skeleton, as
    ``motion`` (the shot the network fills) is. The spline's fill holds the same keys as the
    network's (:func:`spline_fill`); :func:`apply` blends them gap by gap."""

    def __init__(self, motion: Motion, keys, joint_keys=None):
        self.motion, self.keys, self.joint_keys = motion, np.asarray(keys, np.int64), joint_keys

    def model(self, fill: Motion) -> Motion:
        return fill

    def spline(self, spline, cuts=()) -> Motion:
        return spline_fill(spline, self.motion, self.keys, self.joint_keys, cuts)

    def blend(self, decision: TrustDecision, m: Motion | None, s: Motion | None) -> Motion:
        full = (
            self.keys if self.joint_keys is None else self.keys[np.asarray(self.joint_keys, bool).all(axis=1)]
        )
        return apply(decision, m, s, full)


def trusted_fill(inb: TrustedInbetweener, motion: Motion, keys, seed: int = 0, joint_keys=None, dna=None,
                 cuts=(), meet=None):  # fmt: skip
    """The trusted fill of one character, the only one (``tween fill``, the farm and every
    bench that fills shots come here): ``inb`` decides from the full keys how far its network
    is trusted over its spline (:meth:`TrustedInbetweener.decide`; ``cuts`` go to the spline),
    the network fills each stretch between cuts on its own (:func:`fill_across_cuts`; not at
    all where the spline has every gap), the spline fills (not where the network has every
    gap), and the two are blended gap by gap at the decided weights.

    ``meet``: where the two fills meet, an object with ``model(fill)`` (the network's fill,
    a Motion on the model skeleton, carried there), ``spline(spline, cuts)`` (the spline's fill
    there, ``cuts`` the keys' own, in the motion's key frames, whatever the trust) and ``blend(decision, model, spline)`` (either may be None: the other is the
    fill); :class:`OnSkeleton` by default. The fill layer meets them on the character's own
    rig (pipeline.fill.solve), where its spline is filled on the rig's own joints. The window benches
    run the same steps batched (:func:`trusted_fill_windows`: bit for bit this, shot for shot)."""
    keys = np.asarray(keys, np.int64)
    full = keys if joint_keys is None else keys[np.asarray(joint_keys, bool).all(axis=1)]
    d = inb.decide(motion, full, cuts)
    meet = OnSkeleton(motion, keys, joint_keys) if meet is None else meet
    extra = {k: v for k, v in (("joint_keys", joint_keys), ("dna", dna)) if v is not None}
    m = (
        meet.model(fill_across_cuts(inb.model, motion, keys, d.cuts, seed=seed, **extra))
        if d.weight > 0.0
        else None
    )
    s = meet.spline(inb.spline, cuts) if d.weight < 1.0 else None  # the keys' cuts, whatever the trust
    return meet.blend(d, m, s)


@dataclass
class WindowFills:
    """:func:`trusted_fill_windows`' fills, each (rotations, roots) of the N shots: the
    network's, the spline's and the decided one; the ``decisions``, the model's ``weights``
    per shot and frame (N, T), the ``seconds`` the network's fill and the probes took, and
    per shot which in-betweener was decided on (``chosen``: 0 the model, k the k-th of the
    alternatives)."""

    model: tuple
    spline: tuple
    decided: tuple
    decisions: list
    weights: np.ndarray
    seconds: dict
    chosen: np.ndarray | None = None


def trusted_fill_windows(model, spline, rots, roots, keys, cache: dict | None = None,
                         alternatives=()) -> WindowFills:  # fmt: skip
    """:func:`trusted_fill`'s steps for N shots sharing their ``keys`` on the model skeleton
    (the benchmark's windows: no cuts or overrides), each batched over the shots: the
    network's fill, the spline's, one decision per shot (:func:`decide_batch`, one model call
    a probe; ``cache`` as there) and the blend, gap by gap. ``alternatives`` (a library the
    model ships beside it) are probed as :class:`TrustedInbetweener` probes them, and a
    shot :func:`pick` gives one is filled by it."""
    t0 = time.perf_counter()
    m = fill_windows(model, rots, roots, keys, BATCH, model.skeleton)
    t_model = time.perf_counter() - t0
    s = spline.fill_batch(rots, roots, keys)
    t0 = time.perf_counter()
    decisions = decide_batch(model, spline, rots, roots, keys, cache=cache)
    chosen, filled = np.zeros(len(decisions), np.int64), m
    if alternatives:
        decisions, chosen, filled = _alternatives_windows(model, spline, rots, roots, keys, decisions, m,
                                                          alternatives)  # fmt: skip
    t_probes = time.perf_counter() - t0
    w = np.stack([d.frame_weights(keys, np.shape(rots)[1]) for d in decisions])
    seconds = {"model_fill": t_model, "probes": t_probes}
    return WindowFills(m, s, blend_arrays(w, *filled, *s), decisions, w, seconds, chosen)


def _alternatives_windows(model, spline, rots, roots, keys, decisions, fills, alternatives):
    """(decisions, chosen, fills) with each shot's in-betweener picked among ``model`` and
    the ``alternatives`` by their probes (:func:`pick` under the model's :func:`choice_rule`,
    on the shots :func:`probes_beside` leaves open); an alternative fills only the shots it is
    picked for."""
    rule = choice_rule(model, alternatives)
    chosen = np.zeros(len(decisions), np.int64)
    todo = np.array([i for i, d in enumerate(decisions) if probes_beside(model, d)], np.int64)
    if not len(todo):
        return decisions, chosen, fills
    options = [[decisions[i] for i in todo]]
    options += [decide_batch(a, spline, rots[todo], roots[todo], keys, model.skeleton) for a in alternatives]
    names = [model.name] + [a.name for a in alternatives]
    chosen[todo] = [pick([o[n].score for o in options], *rule) for n in range(len(todo))]
    picked = list(decisions)
    for n, i in enumerate(todo):
        picked[i] = replace(options[chosen[i]][n], source=names[chosen[i]])
    out_r, out_p = np.array(fills[0], copy=True), np.array(fills[1], copy=True)
    for k, alt in enumerate(alternatives, start=1):
        sel = np.flatnonzero(chosen == k)
        if len(sel):
            out_r[sel], out_p[sel] = fill_windows(alt, rots[sel], roots[sel], keys, BATCH, model.skeleton)
    return picked, chosen, (out_r, out_p)


def probes_beside(primary, first: TrustDecision) -> bool:
    """Whether the alternatives are probed beside ``primary`` on a shot it decided ``first``
    on: not where the primary keeps the shots whose keys are as familiar as its training
    data (``keeps_own``, familiarity 1; :mod:`pipeline.infer.novelty`). There its probes,
    holes twice the shot's gaps, undersell it: on the blocking bench's eval shots keyed every
    30 the library shipped beside the network was decided on for 12 % of them, at 1.35x the
    network's error (docs/models.md)."""
    return not (primary.capabilities.keeps_own and (first.familiarity or 0.0) >= 1.0)


def choice_rule(primary, alternatives=()) -> tuple[list[float], float | None]:
    """(margins, floor) of :func:`pick` for ``alternatives`` probed beside ``primary``: each
    candidate's ``probe_margin``, what a later one must beat it by (the primary's; and a
    library's, whose probes, holes twice the shot's gaps, undersell it against a network's),
    and with ``keeps_own`` a floor of 0: an alternative must beat the spline on the probes. A
    library that has nothing like the keys gives the spline at the probes (score 0), while the
    network's own decision, worse than the spline at the probes' long holes, still blends in
    what it does better between the keys (experiments/library_margin.py)."""
    margins = [float(m.capabilities.probe_margin) for m in (primary, *alternatives)]
    return margins, 0.0 if primary.capabilities.keeps_own else None


def pick(scores, margin=0.0, floor=None) -> int:
    """Which of several in-betweeners probed on one shot is decided on, from their probes'
    ``scores`` (None: no probes), in order, the first the primary: the last alternative with
    a score that beats every earlier candidate's score (where it has one) by that candidate's
    ``margin`` and the ``floor`` (None: none); else the primary. ``margin``: one per
    candidate, or one number, the primary's (the others' 0). Equal scores keep the earlier."""
    n = len(scores)
    margins = list(margin) if isinstance(margin, (list, tuple)) else [float(margin)] + [0.0] * (n - 1)
    chosen = 0
    for i in range(1, n):
        sc = scores[i]
        if sc is None or (floor is not None and not sc > floor):
            continue
        if all(scores[j] is None or sc > scores[j] + margins[j] for j in range(i)):
            chosen = i
    return chosen


def trusted(inbetweener, trust: str = "auto", alternatives=()):
    """``inbetweener`` wrapped in a :class:`TrustedInbetweener` when it is a network or a
    library (what the fill layer calls once, on what ``load_inbetweener`` gave it), with the
    ``alternatives`` it is probed against; the spline and interpolation
    (``capabilities.any_rig``) come back as they are: they have nothing to decide."""
    if isinstance(inbetweener, TrustedInbetweener) or inbetweener.capabilities.any_rig:
        return inbetweener
    return TrustedInbetweener(inbetweener, trust=trust, alternatives=alternatives)
