"""``tween library build`` and ``tween library info``: a studio's takes as a motion library."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import typer

from pipeline.errors import printable
from pipeline.library.options import LOCK_WAIT_S, LibraryBuildOptions, check_lock_wait, with_library_options
from pipeline.library.store import check_fillable, open_library, verify


@with_library_options
def build_command(
    folder: Path = typer.Argument(
        ..., help="Folder of takes (BVH and USD, any humanoid rig; searched recursively)."
    ),
    out: Path = typer.Option(
        ..., "--out", help="The library folder to write (new, or an existing library with --add)."
    ),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="A progress bar on stderr."),
    progress_lines: bool = typer.Option(
        False,
        "--progress-lines",
        hidden=True,
        help="Progress as 'tween: library progress D/T' lines on stderr "
        "(the farm's channel), at most two a second.",
    ),
    lock_wait: float = typer.Option(
        LOCK_WAIT_S, "--lock-wait", help="Seconds to wait for another build of the library (then exit 2)."
    ),
    opts: LibraryBuildOptions = None,
):
    """Read a studio's takes into a motion library for `tween fill --library`."""
    from pipeline.library.build import build

    opts.check()
    check_lock_wait(lock_wait)
    res = build(folder, out, include=opts.include, licence=opts.licence, name=opts.name, add=opts.add,
                progress=progress, mirror=opts.mirror,
                on_progress=_progress_lines() if progress_lines else None, lock_wait=lock_wait)  # fmt: skip
    typer.echo(json.dumps(res, indent=1))


#: The line ``--progress-lines`` writes (workers.train_tasks reads it).
PROGRESS_LINE = "tween: library progress {done}/{total}"


def _progress_lines():
    last = [0.0]

    def show(done: int, total: int, name: str) -> None:
        now = time.monotonic()
        if done == total or now - last[0] >= 0.5:
            last[0] = now
            print(PROGRESS_LINE.format(done=done, total=total), file=sys.stderr, flush=True)

    return show


def info_command(library: Path = typer.Argument(..., help="A library folder.")):
    """What a library holds: takes, frames, hours, licence and hash; its skeleton and frame
    rate (as the fill checks them) and every frame of its arrays checked first (a damaged file
    is one line naming it, exit 2)."""
    lib = open_library(library)
    check_fillable(lib)  # what the fill refuses, refused here too
    verify(lib)  # a TD runs info to check a library: all of it, before a line is printed
    typer.echo(lib.describe())
    for t in lib.manifest["takes"]:  # a file name may hold a newline: one take, one line
        typer.echo(f"  {printable(t['name'])}: {t['frames']} frames ({printable(t.get('rig', ''))})")


def register(app: typer.Typer) -> None:
    lib = typer.Typer(
        name="library", help="A studio's motion library: build it, look at it.", no_args_is_help=True
    )
    lib.command("build")(build_command)
    lib.command("info")(info_command)
    app.add_typer(lib, name="library")
