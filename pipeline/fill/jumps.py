"""Keys that teleport: the body moves between two keys as no person can.

A capture glitch (ten CMU takes of subject 7 start with a frame 1.7-2.7 m from the next) or
a cut keyed inside one shot. The fill still honours every key, so the frames between such
keys cross the distance at that speed; the plan says so on stderr and records the pairs
(``tween:keyJumps`` on the filled animation, ``jumps`` in the fill's JSON), so a TD sees
why a gap moves impossibly fast instead of finding it in dailies, and the trusted fill
treats each pair as a cut (pipeline.infer.trust).

Two rules, each a bound on a human body, not a fitted value: faster than anyone runs
(:data:`JUMP_MPS`), or a horizontal pace that differs from the gaps on both sides of it
by more than :data:`JUMP_DV` at an acceleration above :data:`JUMP_ACCEL`, carrying the body
:data:`JUMP_M` or more off that pace (a spike: the body would have to brake and start again
harder than any sprinter). The second sees a glitch keyed every 10 frames at 30 fps (5-7 m/s
between walking gaps), which the first cannot. Measured: on the 61 CMU takes converted at 30 and 60 fps, keyed on every frame or
every 10, they flag exactly the ten glitch takes; on the Bandai train and eval clips' root
paths (every frame, keys every 5, 10 and 30 frames: 329,591 to 2,914 pairs) nothing.
"""

from __future__ import annotations

import numpy as np

from pipeline.motion.rotations import batch_quat_apply, batch_quat_mul, batch_quat_normalize

#: Speed of the body between two keys above which they are said to jump (m/s): above the
#: fastest sprint measured (12.4 m/s at its peak), far below a capture glitch keyed on every
#: frame (144 m/s on CMU take 07_05; 14.4 m/s keyed every 10 frames at 60 fps).
JUMP_MPS = 12.5
#: A gap whose horizontal pace differs from each neighbouring gap's by more than this (m/s)...
JUMP_DV = 3.0
#: ...at more than this acceleration (m/s², 1.5 g: a sprint start or stop is 5-10)...
JUMP_ACCEL = 15.0
#: ...carrying the body this much further (or less far) in the gap than that pace would (m):
#: a glitch's metres, not the centimetres of capture jitter on keys a frame apart.
JUMP_M = 0.5
#: Keys whose world transforms are held at once (float64 temporaries follow the block, not
#: a shot keyed on every one of its frames).
BLOCK = 2048


def body_centre(parents: np.ndarray, rot: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """Mean skeleton-space position of every joint (K, 3) at each key, from skeleton-ordered
    local rotations (K, J, 4) and translations (K, J, 3): where the whole body is, so one
    joint flipping (a wrist glitch) moves it little and the body teleporting moves it fully.
    Plain numpy quaternion arithmetic, not scipy ``Rotation`` objects per joint (those took
    11.5 s for a shot of 36,000 keys on a 100-joint rig, this 1.5 s): the plan runs it on every key."""
    K, J = rot.shape[:2]
    out = np.empty((K, 3))
    for s in range(0, K, BLOCK):
        b = slice(s, s + BLOCK)
        n = len(rot[b])
        g = np.empty((n, J, 4))
        p = np.empty((n, J, 3))
        for j, par in enumerate(parents):  # parents come before their children
            r, t = batch_quat_normalize(rot[b, j]), trans[b, j].astype(np.float64)
            if par < 0:
                g[:, j], p[:, j] = r, t
            else:
                g[:, j] = batch_quat_mul(g[:, par], r)
                p[:, j] = p[:, par] + batch_quat_apply(g[:, par], t)
        out[b] = p.mean(axis=1)
    return out


def key_jumps(times: np.ndarray, centre_m: np.ndarray, tcps: float, up: int | None = None) -> list[dict]:
    """The consecutive key pairs the body centre (metres, (K, 3)) jumps between: faster than
    :data:`JUMP_MPS` (``"why": "speed"``), or a spike in horizontal pace (``"spike"``;
    ``up``: the index of the up axis, None to judge all three). Each ``{"from", "to"}``
    (time codes), ``metres``, ``seconds``, ``mps``, ``why``."""
    times = np.asarray(times, np.float64)
    step = np.diff(np.asarray(centre_m, np.float64), axis=0)
    dt = np.diff(times) / float(tcps)
    dist = np.linalg.norm(step, axis=-1)
    pace = step / dt[:, None]
    if up is not None:
        pace[:, up] = 0.0
    spike = np.zeros(len(dt), bool)
    if len(dt) > 1:
        # Against each neighbour: the change of pace and the acceleration it takes.
        dv = np.linalg.norm(np.diff(pace, axis=0), axis=-1)
        hard = (dv > JUMP_DV) & (dv > JUMP_ACCEL * (dt[:-1] + dt[1:]) / 2)
        before = np.r_[True, hard & (dv * dt[1:] > JUMP_M)]  # the first gap has none before it
        after = np.r_[hard & (dv * dt[:-1] > JUMP_M), True]
        spike = before & after
    fast = dist > JUMP_MPS * dt
    return [
        {
            "from": float(times[i]),
            "to": float(times[i + 1]),
            "metres": round(float(dist[i]), 3),
            "seconds": round(float(dt[i]), 4),
            "mps": round(float(dist[i] / dt[i]), 1),
            "why": "speed" if fast[i] else "spike",
        }
        for i in np.flatnonzero(fast | spike)
    ]


def jump_line(jumps: list[dict]) -> str:
    """The stderr words for a character's jumps: the first one, and how many more."""
    j = jumps[0]
    more = f" and {len(jumps) - 1} more pair(s)" if len(jumps) > 1 else ""
    why = "faster than anyone runs" if j["why"] == "speed" else "a change of pace no body makes"
    return (
        f"keys {j['from']:.10g} and {j['to']:.10g}{more}: the body moves {j['metres']:.2f} m in "
        f"{j['seconds']:.3g} s ({j['mps']:.0f} m/s, {why}): a capture glitch or a cut? filled as keyed"
    )
