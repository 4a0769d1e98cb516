"""Parsing key and range options: ``1001,1012,1030``, ``1001-1100x8``, ``1010-1050``."""

from __future__ import annotations

import re

import numpy as np

from pipeline.errors import TweenError

_NUM = r"-?\d+(?:\.\d+)?"
_RANGE = re.compile(rf"^({_NUM})-({_NUM})(?:x(\d+(?:\.\d+)?))?$")


def parse_keys(spec: str) -> np.ndarray:
    """Sorted unique key time codes. ``a-bxN`` is every N from a up to b (Houdini/Nuke style)."""
    out: list[float] = []
    for part in (p.strip() for p in str(spec).split(",")):
        if not part:
            continue
        m = _RANGE.match(part)
        try:
            if m:
                a, b, step = float(m.group(1)), float(m.group(2)), float(m.group(3) or 1)
                if b < a or step <= 0:
                    raise ValueError
                out.extend(np.arange(a, b + 1e-9, step).tolist())
            else:
                out.append(float(part))
        except ValueError:
            raise TweenError(
                f"--keys {spec!r}: {part!r} is not a time code or a range like 1001-1100x8"
            ) from None
    if not out:
        raise TweenError(f"--keys {spec!r}: no key times")
    return np.unique(np.array(out, np.float64))


def parse_range(spec: str) -> tuple[float, float]:
    m = _RANGE.match(str(spec).strip())
    if not m or m.group(3):
        raise TweenError(f"--range {spec!r}: expected START-END, e.g. 1010-1050")
    a, b = float(m.group(1)), float(m.group(2))
    if b < a:
        raise TweenError(f"--range {spec!r}: end is before start")
    return a, b


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
