"""USD commands of the ``tween`` CLI: ``convert`` (BVH → shot), ``fill-local`` (in process),
``approve`` and ``publish`` (dailies, :mod:`pipeline.usd.dailies`).

``tween fill`` (the farm) is defined in ``workers/cli.py``; ``fill-local`` runs the same
fill in this process, for debugging.
"""

from __future__ import annotations

import json
import math
import os
import re
import sys
import threading
import time
from contextlib import ExitStack, redirect_stderr
from dataclasses import replace
from pathlib import Path

import typer
from tqdm import tqdm
from tqdm.contrib import DummyTqdmFile

from pipeline.atomic import writable
from pipeline.errors import TweenError
from pipeline.fill.api import fill_shot
from pipeline.fill.options import NOT_NETWORKS, FillOptions, with_fill_options
from pipeline.library.store import setting_library
from pipeline.progress import interval
from pipeline.usd.write import check_shot_name


def _number(opt: str, text: str) -> float:
    """``text`` as a finite number, or one line naming the option."""
    try:
        v = float(text)
    except ValueError:
        raise TweenError(f"{opt} {text!r}: not a number") from None
    if not math.isfinite(v):
        raise TweenError(f"{opt} {text!r}: must be a finite number")
    return v


def _convert_options(keys_every: str, start: str, fps: str | None, up: str, name: str, frames: str | None):
    """``tween convert``'s options, parsed: (key spacing, first time code, shot rate or None,
    source frame span or None); a bad one is one line naming it."""
    from pxr import Sdf

    if not re.fullmatch(r"\s*\d+\s*", keys_every) or int(keys_every) < 1:
        raise TweenError(f"--keys-every {keys_every!r}: expected a whole number of frames, 1 or more")
    every = int(keys_every)
    t0 = _number("--start", start)
    if abs(t0) >= 2.0**40:  # beyond it consecutive frames (or sub-frames) round onto each other
        raise TweenError(f"--start {start!r}: out of range (a time code below 1e12)")
    rate = None
    if fps is not None:
        rate = _number("--fps", fps)
        if not 0 < rate <= 1000:
            raise TweenError(f"--fps {fps!r}: must be above 0 and at most 1000")
    if up.lower() not in ("y", "z"):
        raise TweenError(f"--up {up!r}: must be y or z")
    if not Sdf.Path.IsValidIdentifier(name):
        raise TweenError(
            f"--name {name!r}: not a USD prim name (letters, digits, _; not starting with a digit)"
        )
    span = None
    if frames is not None:
        m = re.fullmatch(r"\s*(\d+)\s*-\s*(\d+)\s*", frames)
        if not m:
            raise TweenError(f"--frames {frames!r}: expected A-B, source frame numbers, e.g. 0-120")
        span = int(m[1]), int(m[2])
    return every, t0, rate, span


def _check_shot_path(out: Path, force: bool, source: Path | None = None) -> None:
    """One line if the shot cannot be written at ``out`` (never over ``source``, the input)."""
    if source is not None and out.is_file() and not out.is_symlink() and source.is_file():
        if os.path.samefile(out, source):
            raise TweenError(f"{out}: is the BVH file being converted; give the shot another name")
    if out.is_dir():
        raise TweenError(f"{out}: is a folder; give the shot's file name (e.g. {out / 'shot.usda'})")
    try:
        str(out.absolute()).encode("utf-8")
    except UnicodeEncodeError:  # usd-core writes UTF-8 paths only
        raise TweenError(f"{out}: the path is not UTF-8 text, which USD cannot write; rename it") from None
    if out.suffix.lower() not in (".usda", ".usdc", ".usd"):  # USD reads the extension in any case
        raise TweenError(f"{out}: the shot must end in .usda, .usdc or .usd")
    # A name `tween fill` refuses (a newline, a leading dot, too long, a fill layer's) is
    # refused here by the fill's own check: a shot no fill can be made of is not written.
    check_shot_name(str(out), new=True)
    if not out.parent.is_dir():
        raise TweenError(f"{out}: the folder {out.parent} does not exist")
    # The mode bits too, as the fill's layers: a read-only (published) folder stays untouched even for root.
    if not writable(out.parent):
        raise TweenError(f"{out}: the folder {out.parent} is read-only")
    if (out.exists() or out.is_symlink()) and not force:  # fill layers may sublayer it
        raise TweenError(f"{out}: exists; pass --force to replace it (fills of it keep pointing at it)")


def convert(
    bvh: Path = typer.Argument(..., help="BVH motion file (.bvh or .bvh.gz)."),
    out: Path = typer.Argument(..., help="USD shot to write (.usda or .usdc)."),
    keys_every: str = typer.Option("1", "--keys-every", help="Keep every Nth frame as a key (blocking)."),
    start: str = typer.Option("1001", "--start", help="Time code of the first frame."),
    fps: str = typer.Option(None, "--fps", help="Shot rate (resampled; default: the BVH's)."),
    up: str = typer.Option("y", "--up", help="Stage up axis: y or z."),
    frames: str = typer.Option(None, "--frames", help="Source frame span to keep, e.g. 0-120."),
    name: str = typer.Option("Character", "--name", help="Name of the SkelRoot prim."),
    force: bool = typer.Option(False, "--force", help="Replace OUT if it exists."),
):
    """BVH → UsdSkel shot with a skinned box mannequin."""

    from pxr import Tf

    from pipeline.motion.bvh import read_bvh
    from pipeline.usd.convert import write_shot

    # Numbers are parsed here, not by typer, so that a bad value is one line naming the
    # option (typer's own message is a multi-line usage box). Nothing is read or written
    # before the options and the output path check out.
    every, t0, rate, span = _convert_options(keys_every, start, fps, up, name, frames)
    _check_shot_path(out, force, bvh)
    motion = read_bvh(bvh)
    n = len(motion)
    if span:
        a, b = span
        if not a < b < n:
            raise TweenError(f"--frames {frames!r}: need A < B within the clip's frames 0-{n - 1} ({bvh})")
        motion = motion.slice(a, b + 1)
    if len(motion) < 2:
        raise TweenError(f"{bvh}: fewer than two frames to convert")
    if rate is not None and math.floor((len(motion) - 1) * rate / motion.fps + 1e-9) < 1:
        raise TweenError(f"--fps {fps!r}: the shot would have fewer than two frames")
    try:
        path = write_shot(motion, out, start=t0, fps=rate, keys_every=every, up_axis=up.upper(), name=name)
    except (OSError, Tf.ErrorException) as e:
        why = " ".join(str(getattr(e, "strerror", None) or e).split())
        raise TweenError(f"{out}: cannot write the shot: {why}") from None
    typer.echo(path)


#: The studio's library, as the farm reads it (workers/settings.py): every fill that names none uses it.
LIBRARY_VAR = "TWEEN_LIBRARY"


def _studio_library(opts: FillOptions) -> FillOptions:
    """``opts`` with the studio's library (``$TWEEN_LIBRARY``) when it names none, as ``tween
    fill`` does: an empty variable is none, a fill asking for a curve (--model spline) gets the
    curve (no network to probe beside it). A blank one, or a folder that is no library, is one
    line naming the variable and the path."""
    raw = os.environ.get(LIBRARY_VAR, "")
    if opts.library or not raw or opts.model in NOT_NETWORKS:
        return opts
    if not raw.strip():  # the farm's wording (workers/settings.py)
        raise TweenError(f"{LIBRARY_VAR}={raw!r}: empty; give library a value, or leave it out")
    return replace(opts, library=setting_library(raw, f"{LIBRARY_VAR}={raw}"))  # as the farm's


#: Seconds a fill runs before its bar shows (as ``tween library build``'s): a fill of a second
#: draws nothing.
BAR_DELAY = 1.0
#: Seconds between redraws while one step runs (a character of 30,000 frames, the layers), so
#: that the bar's clock runs rather than freezing. Not through usd-core's layer Save, which holds
#: the GIL (19 s of the 24 s that the layers of 16 characters × 30,000 frames took).
TICK = 1.0


class _FillBar:
    """``fill_shot``'s on_progress as a tqdm bar on stderr over the takes × characters and the
    layers. Made at the first call, once the shot is validated: a refused shot is its one line.
    As ``tween library build``'s, a terminal's only (tqdm's ``disable=None``): in a log or a
    pipe, fill-local's stderr stays its notes, warnings and last line, which scripts and the
    tests count. Notes said while it shows (a trust decision) are printed above it."""

    def __init__(self, shot: Path, on: bool):
        self.shot, self.on, self.bar = shot, on, None
        self._stack = ExitStack()
        self._stop = threading.Event()

    def __call__(self, done: int, total: int, what: str) -> None:
        if self.bar is None:
            err = sys.stderr
            self.bar = tqdm(total=total, desc=f"fill {self.shot.name}", unit="step", file=err, postfix=what,
                            disable=not self.on or None, mininterval=interval(err), delay=BAR_DELAY)  # fmt: skip
            if not self.bar.disable:
                # Lines printed mid-fill go above the bar, not into it; the clock runs on.
                self._stack.enter_context(redirect_stderr(DummyTqdmFile(err)))
                ticker = threading.Thread(target=self._tick, name="fill-local bar", daemon=True)
                ticker.start()
                self._stack.callback(ticker.join)
                self._stack.callback(self._stop.set)
        self.bar.set_postfix_str(what, refresh=False)
        self.bar.update(done - self.bar.n)

    def _tick(self) -> None:
        """Redraws the bar every TICK seconds once it shows (after BAR_DELAY), so that its
        elapsed time runs through a long step (a character of 30,000 frames, the layers)."""
        bar = self.bar
        while not self._stop.wait(TICK):
            if time.time() >= bar.start_t + bar.delay:
                bar.refresh()

    def __enter__(self):
        return self

    def __exit__(self, kind, *_):
        self._stack.close()  # the ticker stopped, stderr as it was
        if self.bar is not None:
            self.bar.leave = kind is None  # a fill that failed: its error line stands alone
            self.bar.close()


@with_fill_options
def fill_local(
    shot: Path = typer.Argument(..., help="USD shot."),
    job_id: str = typer.Option("", "--job-id", help="Idempotency key: a layer with this id is reused."),
    progress: bool = typer.Option(
        True, "--progress/--no-progress", help="A progress bar on a terminal's stderr."
    ),
    opts: FillOptions = None,
):
    """Fill a shot in this process and print the result as JSON."""

    with _FillBar(shot, progress) as bar:
        result = fill_shot(str(shot), _studio_library(opts), job_id=job_id, on_progress=bar)
    print(f"tween: filled {shot} -> {result['layer']}", file=sys.stderr)
    typer.echo(json.dumps(result, indent=1))


def register(app: typer.Typer) -> None:
    """Adds this package's commands to ``app``, in the order ``tween --help`` lists them."""
    app.command()(convert)
    app.command("fill-local")(fill_local)
