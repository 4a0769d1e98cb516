"""Keys that teleport: the body moves between two keys faster than any person runs.

A capture glitch (ten CMU takes of subject 7 start with a frame 1.7-2.7 m from the next) or
a cut keyed inside one shot. The fill still honours every key, so the frames between such
keys cross the distance at that speed; the plan says so on stderr and records the pairs
(``tween:keyJumps`` on the filled animation, ``jumps`` in the fill's JSON), so a TD sees
why a gap moves impossibly fast instead of finding it in dailies.
"""

from __future__ import annotations

import numpy as np

from pipeline.motion.rotations import quat_apply, quat_mul

#: Speed of the body between two keys above which they are said to jump (m/s): above the
#: fastest sprint measured (12.4 m/s at its peak), far below a capture glitch keyed on every
#: frame (144 m/s on CMU take 07_05; 14.4 m/s keyed every 10 frames at 60 fps).
JUMP_MPS = 12.5


def body_centre(parents: np.ndarray, rot: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """Mean skeleton-space position of every joint (K, 3) at each key, from skeleton-ordered
    local rotations (K, J, 4) and translations (K, J, 3): where the whole body is, so one
    joint flipping (a wrist glitch) moves it little and the body teleporting moves it fully."""
    K, J = rot.shape[:2]
    g = np.empty((K, J, 4))
    p = np.empty((K, J, 3))
    for j, par in enumerate(parents):  # parents come before their children
        r, t = rot[:, j].astype(np.float64), trans[:, j].astype(np.float64)
        if par < 0:
            g[:, j], p[:, j] = r, t
        else:
            g[:, j] = quat_mul(g[:, par], r)
            p[:, j] = p[:, par] + quat_apply(g[:, par], t)
    return p.mean(axis=1)


def key_jumps(times: np.ndarray, centre_m: np.ndarray, tcps: float, limit: float = JUMP_MPS) -> list[dict]:
    """The consecutive key pairs whose body centre (metres, (K, 3)) moves faster than ``limit``
    m/s between them: ``{"from", "to"}`` (time codes), ``metres``, ``seconds``, ``mps``."""
    dist = np.linalg.norm(np.diff(centre_m, axis=0), axis=-1)
    dt = np.diff(np.asarray(times, np.float64)) / float(tcps)
    fast = np.flatnonzero(dist > limit * dt)
    return [
        {
            "from": float(times[i]),
            "to": float(times[i + 1]),
            "metres": round(float(dist[i]), 3),
            "seconds": round(float(dt[i]), 4),
            "mps": round(float(dist[i] / dt[i]), 1),
        }
        for i in fast
    ]


def jump_line(jumps: list[dict]) -> str:
    """The stderr words for a character's jumps: the first one, and how many more."""
    j = jumps[0]
    more = f" and {len(jumps) - 1} more pair(s)" if len(jumps) > 1 else ""
    return (
        f"keys {j['from']:.10g} and {j['to']:.10g}{more}: the body moves {j['metres']:.2f} m in "
        f"{j['seconds']:.3g} s ({j['mps']:.0f} m/s, faster than anyone runs): a capture glitch "
        "or a cut? filled as keyed"
    )
