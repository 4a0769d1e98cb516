"""The two ways a farm task fails (both take one message so they survive JSON results), and
the embedded farm's stores on a full disk: told apart from other SQLite errors, and ending
the embedded worker that meets them (its client says why in one line)."""

import os
import signal

from pipeline.errors import DISK_FULL, TweenError


class JobError(TweenError):
    """Final: the job's own input is bad (or the code failed); not retried."""


class TransientError(Exception):
    """Shared storage or a connection hiccup; the task retries with back-off."""


class FarmConnectionError(TweenError):
    """The CLI cannot reach the broker or the result backend (one line, password hidden)."""


#: SQLite's primary codes (an extended code's low byte) SQLITE_FULL, "database or disk is
#: full", and SQLITE_IOERR, "disk I/O error".
_SQLITE_FULL, _SQLITE_IOERR = 13, 10
#: Free space under which a folder's SQLite files cannot grow, and how near a file may come
#: to this process's file size limit before it cannot either (a write adds pages and a journal).
NO_ROOM_BYTES, NEAR_LIMIT_BYTES = 1 << 20, 64 << 10
#: Exit status of an embedded worker whose broker or result store cannot grow (sysexits'
#: EX_IOERR): its client says so in one line (workers/embedded.py).
STORE_FULL_EXIT = 74
#: In an embedded worker's processes (the main one and its pool children): the main one's
#: pid, which exits with STORE_FULL_EXIT on SIGUSR2 (:func:`exit_on_full_store`).
_WORKER_MAIN: int | None = None


def raised_from(e: BaseException | None):
    """``e`` and the errors it was raised from (an SQLAlchemy error's ``orig`` first)."""
    seen = 0
    while e is not None and seen < 20:
        yield e
        e, seen = getattr(e, "orig", None) or e.__cause__ or e.__context__, seen + 1


def _sqlite_code(e: BaseException) -> int | None:
    code = getattr(e, "sqlite_errorcode", None)
    return code & 0xFF if isinstance(code, int) else None


def disk_full(e: BaseException | None) -> bool:
    """Whether ``e``, or an error it was raised from (an SQLAlchemy error's ``orig``), is a
    write that found the disk full: an OSError, or SQLite's SQLITE_FULL."""
    for x in raised_from(e):
        if isinstance(x, StoreFullError) or (isinstance(x, OSError) and x.errno in DISK_FULL):
            return True
        if _sqlite_code(x) == _SQLITE_FULL or "database or disk is full" in str(x):
            return True
    return False


def no_room(folder) -> bool:
    """Whether the files in ``folder`` cannot grow: its file system has (next to) no space left
    for this user, or one of them has (nearly) reached this process's file size limit."""
    try:
        import resource

        st = os.statvfs(folder)
        if st.f_bavail * st.f_frsize < NO_ROOM_BYTES:
            return True
        soft = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
        if soft == resource.RLIM_INFINITY:
            return False
        return any(f.is_file() and f.stat().st_size + NEAR_LIMIT_BYTES > soft for f in os.scandir(folder))
    except (OSError, ImportError, ValueError):
        return False


def store_full(e: BaseException | None, folder) -> bool:
    """Whether ``e`` is a write to an SQLite store in ``folder`` that found no room: a full
    disk (:func:`disk_full`), or SQLite's "disk I/O error" while the folder has no room (SQLite
    says that, not "full", of a write that crosses a file size limit or an fsync on a full
    disk: it was an internal error, or a traceback's two lines)."""
    if disk_full(e):
        return True
    io = any(_sqlite_code(x) == _SQLITE_IOERR or "disk I/O error" in str(x) for x in raised_from(e))
    return io and no_room(folder)


class StoreFullError(TweenError):
    """The embedded farm's SQLite broker or result store cannot grow: its disk is full."""

    def __init__(self, path):
        super().__init__(
            f"{path}: the disk is full (the embedded farm's broker and result store live in this "
            "cache folder, TWEEN_CACHE); free space there or set TWEEN_CACHE to another folder"
        )


def exit_on_full_store() -> None:
    """In an embedded worker's main process (before the pool forks): SIGUSR2, from any of
    its processes (:func:`end_for_full_store`), ends it with STORE_FULL_EXIT; its pool
    children die with it (PR_SET_PDEATHSIG)."""
    global _WORKER_MAIN
    _WORKER_MAIN = os.getpid()
    signal.signal(signal.SIGUSR2, lambda *_: os._exit(STORE_FULL_EXIT))


def end_for_full_store() -> None:
    """Called where an embedded worker's process finds its broker or result store full: no
    result of it can be stored, so the whole worker ends now (the consumer retried the broker
    for a minute, logging each try; a stage whose result could not be stored left its client
    waiting for ever). Elsewhere (a client, a farm worker) it does nothing."""
    if _WORKER_MAIN is not None:
        os.kill(_WORKER_MAIN, signal.SIGUSR2)
