"""What a fill job says when it runs out of time: which of the farm's limits it hit, its value,
and where to raise it (the farm config file, or the setting's environment variable).

Each stage has limits of its own: the fill stages (validate, takes, layer) ``fill_time_limit``
/ ``fill_soft_time_limit``; the review render ``render_time_limit`` / ``render_soft_time_limit``
plus ``render_frame_ms`` for every frame of every take (:func:`render_limits`, worked out when
the job is submitted and carried by the render's message); training its own (``train_*``).

Celery reports a soft limit as a bare ``SoftTimeLimitExceeded()`` raised inside the task, and a
hard limit as ``TimeLimitExceeded(50,)`` stored for the task after its process was killed;
:func:`soft_limit_error` and :func:`failure_message` turn them into one line.
"""

from __future__ import annotations

import math
import os

from workers.errors import JobError
from workers.settings import FarmSettings, config_file


def _settings() -> FarmSettings:
    from workers.app import app

    return app.conf.tween


def _raise_in(variables: str, env=None) -> str:
    """``in <file> or <variables>``, or ``with <variables>`` when the farm config names no
    regular file to edit (``TWEEN_FARM_CONFIG=/dev/null``: no settings file at all)."""
    file = config_file(env)
    if os.path.exists(file) and not os.path.isfile(file):
        return f"with {variables}"
    return f"in {file} or {variables}"


def limit_message(shot: str, setting: str, kind: str, settings: FarmSettings | None = None, env=None) -> str:
    """``fill of <shot> hit the farm's <kind> time limit (<setting> = N s); raise it in <file>
    or TWEEN_<SETTING>``, with the limit that has to stay above it."""
    s = _settings() if settings is None else settings
    msg = (
        f"fill of {shot} hit the farm's {kind} time limit ({setting} = {getattr(s, setting)} s); "
        f"raise it {_raise_in(f'TWEEN_{setting.upper()}', env)}"
    )
    if setting == "fill_soft_time_limit":
        msg += f" (it must stay below fill_time_limit = {s.fill_time_limit} s)"
    elif s.is_redis:
        msg += f" (it must stay below visibility_timeout = {s.visibility_timeout} s)"
    return msg


def soft_limit_error(shot: str, settings: FarmSettings | None = None, env=None) -> JobError:
    """The job's error for ``SoftTimeLimitExceeded`` in a fill-queue task."""
    return JobError(limit_message(shot, "fill_soft_time_limit", "soft", settings, env))


def render_limits(frames: int, takes: int, settings: FarmSettings | None = None) -> tuple[int, int]:
    """(soft, hard) seconds of a review render of ``takes`` takes of ``frames`` frames each:
    ``render_soft_time_limit`` / ``render_time_limit`` plus ``render_frame_ms`` per frame."""
    s = _settings() if settings is None else settings
    work = math.ceil(s.render_frame_ms * max(1, int(frames)) * max(1, int(takes)) / 1000)
    return s.render_soft_time_limit + work, s.render_time_limit + work


def render_limit_message(
    shot: str, kind: str, frames: int, takes: int, settings: FarmSettings | None = None, env=None
) -> str:
    """``review render of <shot> hit the farm's <kind> time limit of N s (<base> = B s +
    render_frame_ms = M ms × F frames × T take(s)); raise …``."""
    s = _settings() if settings is None else settings
    soft, hard = render_limits(frames, takes, s)
    base = "render_soft_time_limit" if kind == "soft" else "render_time_limit"
    return (
        f"review render of {shot} hit the farm's {kind} time limit of {soft if kind == 'soft' else hard} s "
        f"({base} = {getattr(s, base)} s + render_frame_ms = {s.render_frame_ms} ms × {frames} frames × "
        f"{takes} take(s)); raise render_frame_ms or {base} "
        f"{_raise_in(f'TWEEN_RENDER_FRAME_MS / TWEEN_{base.upper()}', env)} where the job is submitted"
    )


def failure_message(
    exc: BaseException,
    shot: str | None,
    settings: FarmSettings | None = None,
    env=None,
    stage: str = "",
    work: dict | None = None,
    silent_s: float | None = None,
) -> str:
    """A failed stage's message for ``tween status``: the hard limit's one line for a task
    killed at its hard time limit (the render's, for the ``review`` stage, sized by ``work``:
    {"frames", "takes"}), else the exception's own text. ``silent_s``: the stage's heartbeats
    had stopped that long before it was killed (:func:`silent_message`)."""
    name = type(exc).__name__
    if name == "TimeLimitExceeded" and silent_s:
        return silent_message(shot or "the shot", stage, silent_s)
    if stage == "review" and name in ("TimeLimitExceeded", "SoftTimeLimitExceeded"):
        work = work or {}
        kind = "hard" if name == "TimeLimitExceeded" else "soft"
        return render_limit_message(
            shot or "the shot", kind, work.get("frames", 1), work.get("takes", 1), settings, env
        )
    if name == "TimeLimitExceeded":
        return limit_message(shot or "the shot", "fill_time_limit", "hard", settings, env)
    if name == "SoftTimeLimitExceeded":
        return limit_message(shot or "the shot", "fill_soft_time_limit", "soft", settings, env)
    return str(exc) or name


def silent_message(shot: str, stage: str, silent_s: float) -> str:
    """A stage killed at its hard time limit whose heartbeats (written every few seconds
    while it runs) had stopped ``silent_s`` before: it did not run out of time, its worker
    could not reach the result backend (a broker or backend outage), or it hung."""
    return (
        f"{stage or 'a stage'} of {shot} was stopped at its hard time limit, but its worker had written no "
        f"heartbeat for the {silent_s:.0f} s before: it lost the farm's result backend (or broker) while "
        "the stage ran, or its process hung, so a longer limit would not help; see the worker's log, "
        "and fill the shot again once the farm answers"
    )


def train_limit_message(what: str, setting: str, settings: FarmSettings | None = None, env=None) -> str:
    """``<what> hit the farm's time limit (<setting> = N s, stopped at 95 %); raise it …``."""
    s = _settings() if settings is None else settings
    return (
        f"{what} hit the farm's time limit ({setting} = {getattr(s, setting)} s; the soft limit is 95 % of "
        f"it); raise it {_raise_in(f'TWEEN_{setting.upper()}', env)}, with the visibility timeout "
        "above it on Redis"
    )
