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
from contextlib import contextmanager
from pathlib import Path

from pipeline.atomic import locked
from pipeline.errors import ShotError, TweenError
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


def owner_tag() -> str:
    """``<pid>@<host>``: who writes a temp file."""
    return f"{os.getpid()}@{HOST}"


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
_FILL_TEMP = re.compile(r"^\.(?P<stem>.+?)\.tween\.v(?P<n>\d+)\..+\.tmp\.usd[ac]?$")


def fill_temps(folder: str | Path, stem: str, n: int) -> list[Path]:
    """The temps of writers of ``stem``'s fill version ``n`` in ``folder`` (:data:`_FILL_TEMP`)."""
    return list(Path(folder).glob(f".{glob.escape(stem)}.tween.v{n:03d}.*.tmp.usd*"))


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
        m = _FILL_TEMP.match(e.name)
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


def write_error(path, exc: BaseException) -> TweenError | None:
    """One-line error for a full disk / too large file while writing ``path``, else None."""
    no = getattr(exc, "errno", None)
    if no in _FULL:
        return TweenError(f"{path}: {_FULL[no]}")
    text = str(exc)
    for no, msg in _FULL.items():
        if os.strerror(no) in text:
            return TweenError(f"{path}: {msg}")
    return None


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
    ``out`` (:func:`pipeline.atomic.locked`: the lock file is removed when released).
    """
    lock = out / f".{stem}.tween.lock"

    def failed(e: OSError) -> BaseException:
        return write_error(lock, e) or ShotError(shot, f"cannot lock {lock}: {e.strerror}")

    with locked(lock, make=lambda: make_dirs(shot, out, created), failed=failed):
        yield
