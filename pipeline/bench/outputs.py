"""Where the benches write, checked before they run (a bench reads data for minutes first)."""

from __future__ import annotations

import os
from pathlib import Path

from pipeline.atomic import writable
from pipeline.errors import TweenError


def _writable_folder(option: str, out: Path, probe: Path) -> None:
    """Refuses unless ``probe`` (``out`` or the nearest folder above it that exists) is a
    folder this process may write in."""
    if not probe.is_dir():
        raise TweenError(f"{option} {out}: {probe} is a file, not a folder")
    # The mode bits too: a read-only folder stays untouched even for root.
    if not writable(probe) or not os.access(probe, os.X_OK):
        where = "" if probe == out else f" ({probe} is read-only)"
        raise TweenError(f"{option} {out}: cannot write there{where}")


def _existing(path: Path, option: str = "--out") -> Path:
    """``path``, or the nearest folder above it that exists; a symbolic link on the way that
    leads nowhere is refused (making the folder would fail with "File exists")."""
    probe = path
    while not probe.exists() and probe != probe.parent:
        if os.path.islink(probe):
            raise TweenError(
                f"{option} {path}: {probe} is a symbolic link that leads nowhere (to nothing, or in a loop)"
            )
        probe = probe.parent
    return probe


def check_out_folder(out: Path, option: str = "--out") -> None:
    """A folder the bench may create (with its parents) and write files in; else a one-line
    TweenError naming ``option`` and the path. Creates nothing."""
    out = Path(out)
    _writable_folder(option, out, _existing(out, option))


def check_out_file(out: Path, option: str = "--out") -> None:
    """A file the bench may write (its folder created where missing); else a one-line
    TweenError naming ``option`` and the path. Creates nothing."""
    out = Path(out)
    if out.is_dir():
        raise TweenError(f"{option} {out}: is a folder; give a file name (e.g. {out / 'farm.json'})")
    if out.exists() and not os.access(out, os.W_OK):
        raise TweenError(f"{option} {out}: the file is read-only")
    _writable_folder(option, out, _existing(out.parent, option))
