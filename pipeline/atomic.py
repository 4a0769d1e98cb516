"""A file replaced whole or not at all: written beside its destination under a temporary
name and renamed over it, so a reader (or an interrupted writer) never sees half of it;
whether a folder may be written in, or a file rewritten, at all; and one writer at a time
(:func:`locked`), for what is read, changed and written back."""

from __future__ import annotations

import fcntl
import io
import os
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path


def writable(path: str | Path) -> bool:
    """Whether this process may write in the folder ``path``, or rewrite the file ``path``, by
    its access and by its mode bits: a read-only (published) folder or layer stays untouched
    even for root, whom access lets write."""
    return os.access(path, os.W_OK) and bool(Path(path).stat().st_mode & 0o222)


@contextmanager
def replacing(path: str | Path, suffix: str = ".tmp") -> Iterator[Path]:
    """A temporary file beside ``path`` (``.NAME.XXXX`` + ``suffix``) for the block to write,
    with the mode a file the user writes gets (mkstemp makes it private); renamed over
    ``path`` when the block ends, removed when it fails."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=suffix)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


@contextmanager
def naming(path: str | Path) -> Iterator[None]:
    """An OSError of the block, which writes the file ``path``, names ``path``: a write that
    finds the disk full names no file, and a temporary's hidden name is not one the user gave."""
    try:
        yield
    except OSError as e:
        raise OSError(e.errno, e.strerror or str(e), str(path)) from None


def write_bytes(path: str | Path, data) -> None:
    """``data`` (bytes or a buffer) as the file ``path``, whole or not at all
    (:func:`replacing`); an OSError names ``path``."""
    with naming(path), replacing(path) as tmp, open(tmp, "wb") as f:
        f.write(data)


def save_torch(obj, path: str | Path) -> None:
    """``torch.save(obj, path)`` whole or not at all, serialised in memory first: torch's own
    file writer turns a full disk into a RuntimeError ("unexpected pos") that names nothing,
    and left its half-written file; here the write's OSError names ``path`` and the
    temporary goes. Only the training imports torch (the ``[train]`` extra)."""
    import torch

    buf = io.BytesIO()
    torch.save(obj, buf)
    write_bytes(path, buf.getbuffer())


@contextmanager
def locked(
    lock: str | Path,
    make: Callable[[], None] | None = None,
    waiting: Callable[[], None] | None = None,
    failed: Callable[[OSError], BaseException] | None = None,
    busy: Callable[[], BaseException] | None = None,
    timeout: float | None = None,
    timed_out: Callable[[], BaseException] | None = None,
) -> Iterator[None]:
    """Holds an exclusive lock (flock) on the file ``lock`` for the block, then removes it.

    ``make()`` runs before each try (it makes the lock's folder); ``waiting()`` once, when
    another process holds the lock (to say so before blocking); ``failed(e)`` turns an error
    opening the lock file into the caller's; ``busy()``, where given, is raised instead of
    waiting for another holder. With ``timeout`` (seconds), the wait ends there and
    ``timed_out()`` (default a TimeoutError naming the file) is raised; without it the wait
    has no end. A waiter that then holds the lock of a file its holder removed sees the inode
    gone and locks the new file instead. A killed holder's lock is released by the kernel, so
    a lock file left behind never blocks anyone.
    """
    lock, told = Path(lock), False
    deadline = None if timeout is None else time.monotonic() + timeout
    while True:
        if make is not None:
            make()
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        except FileNotFoundError:
            if make is None:
                raise
            continue  # the folder was removed meanwhile (another writer's failure)
        except OSError as e:
            if failed is None:
                raise
            raise failed(e) from None
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                if busy is not None:
                    raise busy() from None
                if waiting is not None and not told:
                    waiting()
                    told = True
                if not _flock_by(fd, deadline):
                    raise (timed_out() if timed_out else TimeoutError(f"{lock}: still locked")) from None
            same = _names(lock, fd)
        except BaseException:
            os.close(fd)
            raise
        if same:
            break
        os.close(fd)
    try:
        yield
    finally:
        with suppress(OSError):
            os.unlink(lock)
        os.close(fd)


def _names(lock: Path, fd: int) -> bool:
    """Whether the path ``lock`` still names the file open as ``fd`` (a holder removes it)."""
    st = os.fstat(fd)
    try:
        cur = os.stat(lock)
    except FileNotFoundError:
        return False
    return (cur.st_dev, cur.st_ino) == (st.st_dev, st.st_ino)


def _flock_by(fd: int, deadline: float | None) -> bool:
    """Takes the exclusive flock on ``fd`` before ``time.monotonic()`` reaches ``deadline``
    (None: however long it takes); False when another still holds it then. Polled: flock has
    no timeout of its own, and an alarm signal would work in the main thread only."""
    if deadline is None:
        fcntl.flock(fd, fcntl.LOCK_EX)
        return True
    pause = 0.01
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            time.sleep(min(pause, left))
            pause = min(2 * pause, 0.5)


@contextmanager
def holding(folder: str | Path, busy: Callable[[], BaseException]) -> Iterator[None]:
    """Holds an exclusive lock (flock) on the folder itself for the block, so nothing is
    written in it to lock it (a refusal leaves the folder as it was); raises ``busy()`` where
    another process holds it. A killed holder's lock is released by the kernel."""
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise busy() from None
        yield
    finally:
        os.close(fd)
