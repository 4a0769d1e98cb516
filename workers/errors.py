"""The two ways a farm task fails. Both take one message so they survive JSON results."""

from pipeline.errors import DISK_FULL, TweenError


class JobError(TweenError):
    """Final: the job's own input is bad (or the code failed); not retried."""


class TransientError(Exception):
    """Shared storage or a connection hiccup; the task retries with back-off."""


class FarmConnectionError(TweenError):
    """The CLI cannot reach the broker or the result backend (one line, password hidden)."""


#: SQLite's SQLITE_FULL: "database or disk is full".
_SQLITE_FULL = 13


def disk_full(e: BaseException | None) -> bool:
    """Whether ``e``, or an error it was raised from (an SQLAlchemy error's ``orig``), is a
    write that found the disk full: an OSError, or SQLite's SQLITE_FULL."""
    seen = 0
    while e is not None and seen < 20:
        if isinstance(e, StoreFullError) or (isinstance(e, OSError) and e.errno in DISK_FULL):
            return True
        if getattr(e, "sqlite_errorcode", None) == _SQLITE_FULL or "database or disk is full" in str(e):
            return True
        e, seen = getattr(e, "orig", None) or e.__cause__ or e.__context__, seen + 1
    return False


class StoreFullError(TweenError):
    """The embedded farm's SQLite broker or result store cannot grow: its disk is full."""

    def __init__(self, path):
        super().__init__(
            f"{path}: the disk is full (the embedded farm's broker and result store live in this "
            "cache folder, TWEEN_CACHE); free space there or set TWEEN_CACHE to another folder"
        )
