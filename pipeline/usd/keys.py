"""Parsing key and range options: ``1001,1012,1030``, ``1001-1100x8``, ``1010-1050``.

Every number must be finite; a range ``a-bxN`` needs a <= b and N > 0, and is checked
against the stage range and a bound on the number of keys (:data:`MAX_KEYS`) from its
endpoints, BEFORE it is expanded: ``1001-999999999`` is refused at once, not after
allocating a billion key times.
"""

from __future__ import annotations

import math
import re

import numpy as np

from pipeline.errors import ShotError, TweenError

#: The most keys one ``--keys`` may give (a range is counted before it is expanded).
MAX_KEYS = 1_000_000
#: The most frames a stage range (and so ``--range``) may span.
MAX_FRAMES = 1_000_000
#: The most joint-frames (frames of a fill range × its character's joints) one fill holds: a
#: fill keeps about 100 bytes a joint-frame at once, and 2,000 joints × 100,000 frames ran out
#: of memory after minutes (9.4 GB). 40 million is about 4 GB: a 100-joint rig's 400,000 frames.
MAX_JOINT_FRAMES = 40_000_000
_EPS = 1e-4  # as read.TIME_EPS: time codes closer than this are the same frame

_NUM = r"[-+]?(?:(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][-+]?\d+)?|nan|inf(?:inity)?)"
_SINGLE = re.compile(rf"^\s*({_NUM})\s*$", re.I)
_RANGE = re.compile(rf"^\s*({_NUM})\s*-\s*({_NUM})\s*(?:[xX]\s*(.*?))?\s*$", re.I)


def _fail(shot, opt: str, spec: str, why: str, part: str | None = None):
    if part is not None and part != spec.strip():  # name the part of a list at fault
        why = f"{part!r}: {why}"
    msg = f"{opt} {spec!r}: {why}"
    raise (ShotError(shot, msg) if shot is not None else TweenError(msg)) from None


def _stage(start, end) -> tuple[float, float] | None:
    if start is None or end is None:
        return None
    return float(start), float(end)


def _finite(text: str) -> float | None:
    v = float(text)
    return v if math.isfinite(v) else None


def _range_count(a: float, b: float, step: float) -> float:
    """How many keys ``np.arange(a, b + 1e-9, step)`` gives, without making them (inf if
    too many to count)."""
    n = math.ceil((b + 1e-9 - a) / step) if math.isfinite((b - a) / step) else math.inf
    return max(n, 1)


def _key_range(m, part: str, spec: str, shot, stage) -> tuple[float, float, float, int]:
    """The range ``part`` (matched by ``m``) as (first, last, step, how many keys), checked
    against the stage range ``stage`` when there is one."""
    opt = "--keys"
    a, b = _finite(m.group(1)), _finite(m.group(2))
    if a is None or b is None:
        bad = m.group(1) if a is None else m.group(2)
        _fail(shot, opt, spec, f"{bad!r} is not a finite time code", part)
    step_text = m.group(3)
    if step_text is None:
        step = 1.0
    else:
        sm = _SINGLE.match(step_text)
        step = _finite(sm.group(1)) if sm else None
        if step is None:
            _fail(shot, opt, spec, f"step {step_text!r} is not a finite number", part)
    if b < a:
        _fail(shot, opt, spec, f"the range ends ({b:g}) before it starts ({a:g})", part)
    if step <= 0:
        _fail(shot, opt, spec, f"step {step:g} must be above 0", part)
    n = _range_count(a, b, step)
    if stage:
        s0, s1 = stage
        if a < s0 - _EPS or a > s1 + _EPS:
            _fail(shot, opt, spec, f"key {a:g} is outside the stage range {s0:g}-{s1:g}", part)
        q = (s1 + _EPS - a) / step  # keys of the range up to the stage end: floor(q) + 1
        inside = math.floor(q) + 1 if math.isfinite(q) else math.inf
        if n > inside:
            past = a + inside * step
            _fail(shot, opt, spec, f"key {past:g} is outside the stage range {s0:g}-{s1:g}", part)
    return a, b, step, n


def parse_keys(spec: str, shot=None, start: float | None = None, end: float | None = None) -> np.ndarray:
    """Sorted unique key time codes. ``a-bxN`` is every N from a up to b (Houdini/Nuke style).

    With the stage range (``start``, ``end``) a range must lie within it; ``shot`` names
    the shot in the error (a ShotError then, else a TweenError)."""
    opt, spec = "--keys", str(spec)
    stage = _stage(start, end)
    out: list[float] = []
    ranges: list[tuple[float, float, float]] = []
    count = 0
    for part in (p.strip() for p in spec.split(",")):
        if not part:
            continue
        m = _RANGE.match(part)
        if m:
            a, b, step, n = _key_range(m, part, spec, shot, stage)
            count += n
            if count > MAX_KEYS:
                _fail(shot, opt, spec, f"more than {MAX_KEYS:,} keys", part)
            ranges.append((a, b, step))
            continue
        m = _SINGLE.match(part)
        if not m:
            _fail(shot, opt, spec, f"{part!r} is not a time code or a range like 1001-1100x8")
        v = _finite(m.group(1))
        if v is None:
            _fail(shot, opt, spec, f"{part!r} is not a finite time code")
        count += 1
        if count > MAX_KEYS:
            _fail(shot, opt, spec, f"more than {MAX_KEYS:,} keys")
        out.append(v)
    for a, b, step in ranges:
        out.extend(np.arange(a, b + 1e-9, step).tolist())
    if not out:
        _fail(shot, opt, spec, "no key times")
    return np.unique(np.array(out, np.float64))


def parse_range(
    spec: str, shot=None, start: float | None = None, end: float | None = None
) -> tuple[float, float]:
    """``START-END`` time codes to fill; with the stage range it must lie within it."""
    opt, spec = "--range", str(spec)
    m = _RANGE.match(spec)
    if not m or m.group(3) is not None:
        _fail(shot, opt, spec, "expected START-END, e.g. 1010-1050")
    a, b = _finite(m.group(1)), _finite(m.group(2))
    if a is None or b is None:
        _fail(shot, opt, spec, f"{m.group(1) if a is None else m.group(2)!r} is not a finite time code")
    if b < a:
        _fail(shot, opt, spec, "end is before start")
    if b - a > MAX_FRAMES:
        _fail(shot, opt, spec, f"spans {b - a:.0f} frames; at most {MAX_FRAMES:,} are filled")
    stage = _stage(start, end)
    if stage and (a < stage[0] - _EPS or b > stage[1] + _EPS):
        _fail(shot, opt, spec, f"{a:g}-{b:g} is not within the stage range {stage[0]:g}-{stage[1]:g}")
    return a, b


def key_distance(times, keys) -> np.ndarray:
    """(len(times),) distance from each time code to the nearest of ``keys`` (inf without
    keys): the nearest key on either side of each time, not a times x keys table (at 30,000
    frames keyed every 10 such a table was 1.4 GB)."""
    times = np.asarray(times, np.float64).ravel()
    k = np.sort(np.asarray(keys, np.float64).ravel())
    if not len(k):
        return np.full(len(times), np.inf)
    i = np.searchsorted(k, times)
    below, above = k[np.maximum(i - 1, 0)], k[np.minimum(i, len(k) - 1)]
    return np.minimum(np.abs(times - below), np.abs(above - times))


def merge_times(*groups, eps: float = 1e-4) -> np.ndarray:
    """Sorted union of time codes; of times within ``eps`` of each other the one from the
    earliest group wins (pass authored key times first so they keep their exact values)."""
    ts = [np.asarray(g, np.float64).ravel() for g in groups]
    t = np.concatenate(ts) if ts else np.zeros(0)
    pri = np.concatenate([np.full(len(g), i) for i, g in enumerate(ts)]) if ts else np.zeros(0)
    order = np.lexsort((pri, t))
    out: list[float] = []
    out_pri: list[int] = []
    for k in order:
        if out and t[k] - out[-1] < eps:
            if pri[k] < out_pri[-1]:
                out[-1], out_pri[-1] = float(t[k]), int(pri[k])
            continue
        out.append(float(t[k]))
        out_pri.append(int(pri[k]))
    return np.array(out, np.float64)
