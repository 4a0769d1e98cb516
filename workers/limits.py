"""What a fill job says when it runs out of time: which of the farm's limits it hit, its value,
and where to raise it (the farm config file, or the setting's environment variable).

Celery reports a soft limit as a bare ``SoftTimeLimitExceeded()`` raised inside the task, and a
hard limit as ``TimeLimitExceeded(50,)`` stored for the task after its process was killed;
:func:`soft_limit_error` and :func:`failure_message` turn them into one line.
"""

from __future__ import annotations

from workers.errors import JobError
from workers.settings import FarmSettings, config_file


def _settings() -> FarmSettings:
    from workers.app import app

    return app.conf.tween


def limit_message(shot: str, setting: str, kind: str, settings: FarmSettings | None = None, env=None) -> str:
    """``fill of <shot> hit the farm's <kind> time limit (<setting> = N s); raise it in <file>
    or TWEEN_<SETTING>``, with the limit that has to stay above it."""
    s = _settings() if settings is None else settings
    msg = (
        f"fill of {shot} hit the farm's {kind} time limit ({setting} = {getattr(s, setting)} s); "
        f"raise it in {config_file(env)} or TWEEN_{setting.upper()}"
    )
    if setting == "fill_soft_time_limit":
        msg += f" (it must stay below fill_time_limit = {s.fill_time_limit} s)"
    elif s.is_redis:
        msg += f" (it must stay below visibility_timeout = {s.visibility_timeout} s)"
    return msg


def soft_limit_error(shot: str, settings: FarmSettings | None = None, env=None) -> JobError:
    """The job's error for ``SoftTimeLimitExceeded`` in a fill-queue task."""
    return JobError(limit_message(shot, "fill_soft_time_limit", "soft", settings, env))


def failure_message(
    exc: BaseException, shot: str | None, settings: FarmSettings | None = None, env=None
) -> str:
    """A failed stage's message for ``tween status``: the hard limit's one line for a task
    killed at ``task_time_limit``, else the exception's own text."""
    if type(exc).__name__ == "TimeLimitExceeded":
        return limit_message(shot or "the shot", "fill_time_limit", "hard", settings, env)
    if type(exc).__name__ == "SoftTimeLimitExceeded":
        return limit_message(shot or "the shot", "fill_soft_time_limit", "soft", settings, env)
    return str(exc) or type(exc).__name__
