"""Where the benches write, checked before they run (a bench reads data for minutes first),
and how: a run's files all written whole, or none of them."""

from __future__ import annotations

import os
from contextlib import ExitStack
from pathlib import Path

from pipeline.atomic import naming, replacing, writable
from pipeline.errors import TweenError
from pipeline.outputs import missing_folders, remove_created

#: The files each kind of ``tween bench`` writes in --out (cli.MODES' keys).
OUTPUTS = {
    "": ("bench.json", "bench.md"),
    "--partial-keys": ("partial_keys.json", "partial_keys.md"),
    "--long-gaps": ("long_gaps.json", "long_gaps.md"),
    "--rig-variants": ("rig_bench.json", "rig_bench.md"),
    "--speed": ("speed.json", "speed.md"),
}


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


def refuse_earlier(out: Path, names, force: bool, option: str = "--out") -> None:
    """Refuses, without ``force``, an ``out`` that holds one of the files ``names`` (an earlier
    run's results): nothing a user has is replaced without --force."""
    there = [n for n in names if os.path.lexists(Path(out) / n)]
    if there and not force:
        raise TweenError(
            f"{Path(out) / there[0]}: {option} holds an earlier run's results; give --force to "
            "replace them, or another folder"
        )


def write_outputs(out: Path, texts: dict[str, str]) -> None:
    """The files ``texts`` names (name → text) in the folder ``out``, every one whole or none:
    each written to a temporary beside it first, then all renamed. A failure (a full disk) is
    an OSError naming the file; the earlier files stay as they were, the temporaries go, and
    so do the folders made here."""
    out = Path(out)
    made = missing_folders(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        with ExitStack() as renames:  # leaving it renames each temporary, or removes them all
            for name, text in texts.items():
                with naming(out / name):
                    tmp = renames.enter_context(replacing(out / name))
                    tmp.write_text(text, encoding="utf-8")
    except BaseException:
        remove_created(made)  # (a folder the user had stays)
        raise
