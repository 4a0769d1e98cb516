"""Where a command writes, checked before it writes: a folder it may write in, by name.

Every --out of a command that makes files goes through :func:`refuse_read_only` first (model
folders, libraries, review media), so that a published folder stays untouched and a link
that leads nowhere is named, not met as "File exists" halfway through.
"""

from __future__ import annotations

import os
from pathlib import Path

from pipeline.atomic import writable
from pipeline.errors import TweenError


def given_path(value: str, what: str) -> Path:
    """A path argument or option as given, or one line naming it when it is empty or blank
    (``Path("")`` is the working folder: a job or a run was written there)."""
    if not value.strip():
        raise TweenError(f"{what} {value!r}: empty; give a path")
    return Path(value)


def refuse_read_only(path: str | Path, option: str = "--out", folder: str | Path | None = None) -> None:
    """Raises TweenError when ``path`` cannot be written in: ``folder`` if given, else the
    folder ``path`` is (or, not made yet, the nearest one above it that exists; a file's
    folder). Read-only by its mode bits counts even for root: a published folder stays
    untouched, as ``tween convert`` and ``tween fill`` keep it. A symbolic link that leads
    nowhere is refused too (making the folder would fail with "File exists")."""
    path = Path(path)
    if os.path.islink(path) and not os.path.exists(path):  # else "File exists" when made
        raise TweenError(f"{path}: {option} is a symbolic link that leads nowhere (to nothing, or in a loop)")
    probe = Path(os.path.abspath(folder if folder is not None else path))
    while not probe.is_dir() and probe != probe.parent:
        probe = probe.parent
    if not writable(probe):
        where = "is" if probe == Path(os.path.abspath(path)) else f"is in {probe}, which is"
        raise TweenError(f"{path}: {option} {where} read-only; give a folder you can write")


def missing_folders(path: str | Path) -> list[Path]:
    """``path`` and the folders above it that do not exist yet, outermost first: what making
    ``path`` makes, and what :func:`remove_created` takes back when the write fails."""
    missing, p = [], Path(path)
    while not p.exists() and p != p.parent:
        missing.append(p)
        p = p.parent
    return missing[::-1]


def remove_created(created: list[Path]) -> None:
    """Undoes making the folders ``created`` (outermost first) after a failure: each one still
    empty goes, innermost first; one that holds anything stays."""
    for d in reversed(created):
        try:
            d.rmdir()
        except OSError:
            pass


def file_above(path: str | Path) -> Path | None:
    """The file (not a folder) nearest above ``path`` where a folder would have to be made
    for it, or ``None``: what making ``path``'s folders would fail on with "Not a directory"
    naming a path of its own."""
    probe = Path(os.path.abspath(path)).parent
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    return None if probe.is_dir() else probe


def refuse_under_a_file(out: str | Path, option: str = "--out") -> None:
    """TweenError where a file stands where a folder above ``out`` would be made (making it
    said "Not a directory", naming a hidden folder of its own)."""
    above = file_above(out)
    if above is not None:
        raise TweenError(f"{out}: {option} is inside {above}, which is a file, not a folder")
