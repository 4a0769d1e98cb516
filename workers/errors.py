"""The two ways a farm task fails. Both take one message so they survive JSON results."""

from pipeline.errors import TweenError


class JobError(TweenError):
    """Final: the job's own input is bad (or the code failed); not retried."""


class TransientError(Exception):
    """Shared storage or a connection hiccup; the task retries with back-off."""


class FarmConnectionError(TweenError):
    """The CLI cannot reach the broker or the result backend (one line, password hidden)."""
