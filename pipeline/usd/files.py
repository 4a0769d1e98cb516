"""The files this package writes, written safely: temps named for their writer (so the temps of
a writer that died are found and removed), saves that never overwrite (a temp linked into
place), a full disk as one line naming the file, and the folder lock that serialises the
writers of one shot's versions. :mod:`pipeline.usd.write`, :mod:`pipeline.usd.dailies`,
:mod:`pipeline.usd.convert`, the fill, the renderer and the farm use these names."""

from __future__ import annotations

import errno
import glob
import os
import re
import shutil
import socket
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from pipeline.atomic import locked
from pipeline.errors import ShotError, TweenError, printable
from pipeline.outputs import missing_folders

# Every temp file (or take folder) this package writes is named ``.<base>.<pid>@<host>[.<rand>]
# .tmp[.<ext>]`` (a take folder: ``tween-take.<pid>@<host>.<rand>.tmp``), so the next run into
# that folder can tell the temps of a writer that died (killed mid-save) from those of one
# still writing, and remove them. USD's own safe-save temp (``<name without ext>.<rand>``)
# matches the same pattern. Temps of another host are never touched (its pids mean nothing here).

HOST = re.sub(r"[^A-Za-z0-9-]", "-", socket.gethostname() or "host")[:40] or "host"
_TEMP_RE = re.compile(
    r"^(?:\..+|tween-take)\.(?P<pid>\d+)@(?P<host>[A-Za-z0-9-]+)(?:\.[A-Za-z0-9_]+)?\.tmp(?:\.[^.]+)?$"
)
# Temps of earlier versions (no host): only the fill and review layers had a pid in the name.
_OLD_TEMP_RE = re.compile(r"^\..+\.(?:tween|review)\.v\d+\.(?P<pid>\d+)\.tmp(?:\.[^.]+)?$")

_FULL = {
    errno.ENOSPC: "no space left on device",
    errno.EFBIG: "file too large",
    errno.EDQUOT: "disk quota exceeded",
}


#: Seconds a writer waits for a lock another process holds: the lock of a shot's folder
#: (:func:`folder_lock`) or of a ``--review-layer`` (pipeline.usd.write.write_review). Each is
#: held for the moment of one write, so one held this long is a hung writer's: the wait ends
#: in one line naming the lock and its holder (:func:`lock_timed_out`), not in a wait for ever.
LOCK_WAIT_S = 300.0


def owner_tag() -> str:
    """``<pid>@<host>``: who writes a temp file."""
    return f"{os.getpid()}@{HOST}"


def mark_holder(lock: Path) -> None:
    """Writes who holds ``lock`` into it (:func:`owner_tag`), for a writer that waits in vain
    to name; the lock works without it, so a write that fails is let be."""
    with suppress(OSError), open(lock, "w") as f:
        f.write(owner_tag())


def lock_holder(lock: Path) -> str:
    """Who holds ``lock``, as a line that gives up waiting for it says: the ``<pid>@<host>``
    and since when, where the holder wrote them (:func:`mark_holder`)."""
    try:
        holder = printable(lock.read_text(errors="replace")[:200].strip())
        since = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(lock.stat().st_mtime))
    except OSError:  # released meanwhile, or unreadable
        holder = since = ""
    return f"process {holder}, since {since}" if holder else "a process that did not say who it is"


def lock_timed_out(lock: Path, waited: float, other: str) -> TweenError:
    """The line a writer that waited ``waited`` seconds for ``lock`` (held by ``other``, as
    the line words it) gives up with (:func:`lock_holder`)."""
    return TweenError(
        f"{lock}: {other} still holds this lock after {waited:g} s ({lock_holder(lock)}); "
        "run again once it is done"
    )


def temp_path(final: Path) -> Path:
    """The temp a writer of ``final`` saves to before the atomic rename/link (same folder)."""
    final = Path(final)
    return final.with_name(f".{final.stem}.{owner_tag()}.tmp{final.suffix}")


def pid_alive(pid: int, host: str | None = None) -> bool:
    """False only when ``pid`` certainly is not running on this host (a zombie is dead)."""
    if host and host != HOST:
        return True
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except (OSError, IndexError):
        return True


def dead_temp(name: str) -> bool:
    """Whether ``name`` is a temp of this package whose writer has died."""
    m = _TEMP_RE.match(name)
    if m:
        return not pid_alive(int(m["pid"]), m["host"])
    m = _OLD_TEMP_RE.match(name)
    return bool(m) and not pid_alive(int(m["pid"]))


def review_path(folder: str | Path, stem: str, n: int) -> Path:
    """Version ``n``'s review layer of the shot ``stem`` in ``folder`` (beside its fill layer)."""
    return Path(folder) / f"{stem}.review.v{n:03d}.usda"


#: A fill layer's temp (:func:`temp_path`): ``.<stem>.tween.v<NNN>.<owner>.tmp.usd[ac]``.
FILL_TEMP = re.compile(r"^\.(?P<stem>.+?)\.tween\.v(?P<n>\d+)\..+\.tmp\.usd[ac]?$")


def clean_dead_temps(folder: str | Path, quiet: bool = False) -> list[str]:
    """Removes the temp files and take folders of dead writers in ``folder``, and the review
    layer a dead writer made for the version its temp was to become, where no fill layer of
    that version is there (pipeline.usd.write.link_version writes the review first); returns
    them."""
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for e in entries:
        if not dead_temp(e.name):
            continue
        try:
            if e.is_dir(follow_symlinks=False):
                shutil.rmtree(e.path)
            else:
                os.unlink(e.path)
        except FileNotFoundError:
            continue  # another run cleaned it first
        except OSError:
            continue
        removed.append(e.path)
        m = FILL_TEMP.match(e.name)
        if m and not list(Path(folder).glob(f"{glob.escape(m['stem'])}.tween.v{m['n']}.usd*")):
            review = review_path(folder, m["stem"], int(m["n"]))
            if review.is_file():
                review.unlink(missing_ok=True)
                removed.append(str(review))
    if removed and not quiet:
        print(
            f"tween: removed {len(removed)} file(s) a dead writer left in {folder} (temps, reviews of no fill)",
            file=sys.stderr,
        )
    return removed


class DiskFull(TweenError):
    """A write that ran out of room (:func:`write_error`); ``reason`` says how ("no space left
    on device", "file too large", "disk quota exceeded")."""

    reason = ""
    path = ""


def _full(path, reason: str) -> DiskFull:
    err = DiskFull(f"{path}: {reason}")
    err.reason, err.path = reason, str(path)
    return err


def write_error(path, exc: BaseException) -> TweenError | None:
    """One-line error for a full disk / too large file while writing ``path``, else None."""
    no = getattr(exc, "errno", None)
    if no in _FULL:
        return _full(path, _FULL[no])
    text = str(exc)
    for no, msg in _FULL.items():
        if os.strerror(no) in text:
            return _full(path, msg)
    return None


@contextmanager
def temp_full(what: str) -> Iterator[None]:
    """Around writes into the system temp folder (``tempfile.gettempdir()``, TMPDIR): a full
    disk there is one line naming that folder, saying it is full, and what was being done
    (``what``). The file the write named was in a folder of a random name under it, gone by
    then, and the line said nothing of which disk to free or of TMPDIR. A full disk elsewhere
    (a cache, the shot's folder) keeps its own line."""
    try:
        yield
    except (OSError, DiskFull) as e:
        reason, path = (e.reason, e.path) if isinstance(e, DiskFull) else (_FULL.get(e.errno), e.filename)
        base = tempfile.gettempdir()
        if not reason or not path or not Path(os.path.abspath(path)).is_relative_to(os.path.abspath(base)):
            raise
        raise TweenError(
            f"{base}: the system temp folder is full ({reason}) while {what}; "
            "free space there, or set TMPDIR to a folder with room, and run again"
        ) from None


def discard(tmp: Path) -> None:
    """Removes a temp and any safe-save temp USD left beside it (``<tmp without ext>.<rand>``)."""
    tmp = Path(tmp)
    tmp.unlink(missing_ok=True)
    stem = tmp.name[: -len(tmp.suffix)] if tmp.suffix else tmp.name
    try:
        for p in tmp.parent.glob(f"{glob.escape(stem)}.*"):
            if p.name != tmp.name and _TEMP_RE.match(p.name):
                p.unlink(missing_ok=True)
    except OSError:
        pass


@contextmanager
def saving(final, tmp: Path | None = None):
    """Around a USD or file save whose result goes to ``final``: USD's error diagnostics are
    collected (not printed), a full disk / too large file becomes one TweenError naming
    ``final``, and ``tmp`` (with USD's own temp) is removed on any failure."""
    from pxr import Tf

    try:
        yield
    except BaseException as e:
        if tmp is not None:
            discard(tmp)
        err = write_error(final, e)
        if err is not None:
            raise err from None
        if isinstance(e, Tf.ErrorException):
            first = next((ln.strip() for ln in str(e).splitlines() if ln.strip()), type(e).__name__)
            raise TweenError(f"{final}: cannot write: {first.split(' : ', 1)[-1]}") from None
        raise


def link_new(tmp: Path, final: Path) -> bool:
    """Moves tmp to final only if final does not exist (atomic, never overwrites)."""
    try:
        os.link(tmp, final)
    except FileExistsError:
        return False
    finally:
        tmp.unlink(missing_ok=True)
    return True


def make_dirs(shot: str, out: Path, created: list[Path]) -> None:
    """Creates ``out`` and its missing parents, recording those this call made (undone by
    :func:`pipeline.outputs.remove_created`)."""
    for d in missing_folders(out):
        try:
            d.mkdir()
            created.append(d)
        except FileExistsError:
            pass
        except OSError as e:
            raise write_error(d, e) or ShotError(
                shot, f"cannot create output folder {out}: {e.strerror}"
            ) from None


@contextmanager
def folder_lock(shot: str, out: Path, stem: str, created: list[Path]):
    """Exclusive lock (flock) on ``out/.<stem>.tween.lock``, creating ``out`` when needed.

    Serialises the job-id check and the version allocation of every writer of ``stem`` into
    ``out`` (:func:`pipeline.atomic.locked`: the lock file is removed when released). Another
    holder is waited for :data:`LOCK_WAIT_S` seconds at most (then a TweenError naming it).
    """
    lock = out / f".{stem}.tween.lock"

    def failed(e: OSError) -> BaseException:
        return write_error(lock, e) or ShotError(shot, f"cannot lock {lock}: {e.strerror}")

    wait = LOCK_WAIT_S

    def timed_out() -> BaseException:
        return lock_timed_out(lock, wait, f"another writer of {shot}'s fills")

    with locked(
        lock, make=lambda: make_dirs(shot, out, created), failed=failed, timeout=wait, timed_out=timed_out
    ):
        mark_holder(lock)
        yield
