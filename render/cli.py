"""``tween review``: turntable review media (MP4, frames, contact sheet) for a filled shot."""

from __future__ import annotations

import json
import math
import re
import sys
from contextlib import contextmanager
from pathlib import Path

import typer

from pipeline.errors import TweenError
from pipeline.outputs import missing_folders, refuse_read_only, remove_created
from pipeline.usd.write import (
    check_review,
    latest_review,
    made_layer,
    review_of,
)
from render.output import write_whole
from render.review import earlier_media, render_review
from render.scene import list_takes
from render.timeline import folder_lock

#: Frame sides: H.264 (yuv420p) needs even sides, the renderer at least 16; 7680 is 8K UHD.
MIN_SIDE, MAX_SIDE = 16, 7680
#: Camera orbits over the shot (turntable); more is a blur, not a review.
MAX_TURNS = 100.0


def _size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m:
        raise TweenError(f"--size {text!r}: expected WIDTHxHEIGHT, e.g. 960x540")
    w, h = int(m.group(1)), int(m.group(2))
    for side in (w, h):
        if not MIN_SIDE <= side <= MAX_SIDE or side % 2:
            raise TweenError(
                f"--size {text!r}: width and height must be even numbers from {MIN_SIDE} to {MAX_SIDE}"
            )
    return w, h


_NUM = r"[-+]?(?:\d+(?:\.\d*)?|\.\d+)"


def _range(text: str | None) -> tuple[float, float] | None:
    if text is None:
        return None
    m = re.fullmatch(rf"\s*({_NUM})\s*[:-]\s*({_NUM})\s*", text)
    if not m:
        raise TweenError(f"--frames {text!r}: expected START:END time codes, e.g. 1001:1100")
    a, b = float(m.group(1)), float(m.group(2))
    if not (math.isfinite(a) and math.isfinite(b)):
        raise TweenError(f"--frames {text!r}: time codes must be finite numbers")
    if b < a:
        raise TweenError(f"--frames {text!r}: END is before START")
    return a, b


def _check_options(take: int | None, turns: float) -> None:
    if take is not None and take < 0:
        raise TweenError(f"--take {take}: must be a take number, 0 or more")
    if not math.isfinite(turns):
        raise TweenError(f"--turns {turns}: must be a finite number")
    if abs(turns) > MAX_TURNS:
        raise TweenError(f"--turns {turns:g}: must be from -{MAX_TURNS:g} to {MAX_TURNS:g}")


def _latest_fill(shot: str, fills: str | None) -> tuple[str, str | None]:
    """The stage to render for ``shot``, and the line to say once it rendered: a review layer
    itself (every layer it stacks there); a fill layer's review layer; for a plain shot, the
    review layer of its latest fill, or the shot as it is when it has none yet (said only when
    nothing it rendered was filled)."""
    if not Path(shot).is_file():
        return shot, None  # opening it names the problem
    made = made_layer(shot)
    if made == "a review layer":
        check_review(shot)
        return shot, None
    if made == "a fill layer":  # alone it holds no character: its review stacks it on the shot
        found = review_of(shot)
        return str(found), f"tween: review: {shot}: rendered through its review layer, {found}"
    if made:
        raise TweenError(f"{shot}: {made} holds no character alone; sublayer it over its shot to review it")
    if fills is not None and not fills.strip():  # Path("") is the working folder
        raise TweenError(f"--fills {fills!r}: empty; leave it out for the folder beside the shot")
    if fills is not None and not Path(fills).is_dir():  # a typo would render the unfilled shot
        raise TweenError(f"--fills {fills}: no such folder")
    found = latest_review(shot, fills)
    if found is None:
        return shot, f"tween: review: {shot}: no fill of it yet; rendered the shot as it is"
    return str(found), f"tween: review: {shot}: its latest fill, {found}"


@contextmanager
def _all_or_none(out_dir: str, force: bool):
    """Yields a list for the results of the takes rendered so far. Without ``--force``, a
    review of several takes stopped after some had rendered (Ctrl-C, SIGTERM, an error) takes
    back what they moved into ``out_dir`` (their media, the timeline as it was, the folders it
    made): their media made the same command refuse ("an earlier review of this take"). With
    ``--force`` the media they replaced are gone, and theirs stay (the timeline names them)."""
    out = Path(out_dir)
    created = missing_folders(out)
    timelines = {} if created else {t: t.read_bytes() for t in out.glob("*.otio")}
    done: list[dict] = []
    try:
        yield done
    except BaseException:
        if done and not force:
            with folder_lock(out):
                for r in done:
                    for f in (r["mp4"], r["contact_sheet"], *r["frames"]):
                        Path(f).unlink(missing_ok=True)
                    t = Path(r["timeline"])
                    if t in timelines:
                        write_whole(str(t), timelines[t], "the timeline as it was")
                    else:
                        t.unlink(missing_ok=True)
            remove_created(created)
        raise


def review(
    shot: str = typer.Argument(
        ..., help="Review stage (.usd/.usda/.usdc/.usdz): the shot with its fill layer."
    ),
    take: int | None = typer.Option(
        None, "--take", help="Take N: selects variant takeN of the tweenTake set."
    ),
    all_takes: bool = typer.Option(False, "--all-takes", help="Render every take of the tweenTake set."),
    size: str = typer.Option("960x540", "--size", help="Frame size WIDTHxHEIGHT (even numbers)."),
    side_by_side: bool = typer.Option(
        False, "--side-by-side", help="Stepped keys-only blocking next to the fill."
    ),
    out: str = typer.Option(None, "--out", "-o", help="Output folder (default: ./review/<shot>)."),
    exr: bool = typer.Option(False, "--exr", help="Write frames as half-float linear EXR instead of PNG."),
    camera: str = typer.Option(
        "turntable", "--camera", help="turntable, front or side; or follow / fixed (the turntable so framed)."
    ),
    framing: str = typer.Option(
        None, "--framing", help="follow (default: the camera follows the character) or fixed (today's view)."
    ),
    turns: float = typer.Option(1.0, "--turns", help="Camera orbits over the shot (turntable)."),
    ghosts: bool = typer.Option(False, "--ghosts", help="Translucent key poses along the path."),
    no_frames: bool = typer.Option(False, "--no-frames", help="Only the MP4 and the contact sheet."),
    frames: str = typer.Option(None, "--frames", help="Render only time codes START:END."),
    fills: str = typer.Option(
        None,
        "--fills",
        help="Folder of the shot's fill layers, to find its latest fill (default: beside the shot).",
    ),
    force: bool = typer.Option(
        False,
        "--force",
        help="Replace the media an earlier review of these takes left in --out: its movie, contact sheet and every numbered frame (a narrower --frames, --exr or --no-frames leaves none of the old).",
    ),
) -> None:
    """Renders review media for a filled shot: H.264 MP4, numbered frames, contact sheet."""
    # Long because its 14 option declarations are half of it (typer reads them from the
    # signature); the body checks them, then renders each take.

    # Every option is checked here, before anything is imported, read or written.
    w, h = _size(size)
    fr = _range(frames)
    _check_options(take, turns)
    if camera not in ("turntable", "front", "side", "follow", "fixed"):
        raise TweenError(f"--camera {camera!r}: must be turntable, front, side, follow or fixed")
    if framing not in (None, "follow", "fixed") or (
        camera in ("follow", "fixed") and framing not in (None, camera)
    ):
        raise TweenError(f"--framing {framing!r}: must be follow or fixed (and agree with --camera {camera})")
    if all_takes and take is not None:
        raise TweenError("--all-takes: give --take N or --all-takes, not both")
    if out is not None and not out.strip():
        raise TweenError("--out '': give a folder (without --out: ./review/<shot>)")

    given, (shot, said) = shot, _latest_fill(shot, fills)
    out_dir = out or str(Path("review") / Path(shot).name.split(".")[0])
    refuse_read_only(out_dir, "--out")  # a published folder stays untouched, even for root
    takes = [take]
    if all_takes:
        takes = (list_takes(shot) if Path(shot).exists() else []) or [None]
    # Nothing the user has is replaced without --force: an earlier review's movie may be the
    # one sent on. Checked before the options that need the stage (as bench checks its --out),
    # and for every take before the first renders (no partial output).
    if not force and (there := earlier_media(shot, out_dir, takes, exr, not no_frames)):
        raise TweenError(
            f"{there}: --out holds an earlier review of this take; give --force to replace its media, or another --out"
        )
    summaries = []
    with _all_or_none(out_dir, force) as done:
        for t in takes:
            result = render_review(
                shot, out_dir, take=t, size=(w, h), side_by_side=side_by_side, exr=exr, camera=camera,
                turns=turns, ghosts=ghosts, write_frames=not no_frames, frame_range=fr, progress=True,
                framing=framing,
            )  # fmt: skip
            done.append(result)
            summary = {k: v for k, v in result.items() if k not in ("frames", "frame_numbers", "timecodes")}
            summary["frame_count"] = len(result["frame_numbers"])
            summary["frames_dir"] = out_dir if result["frames"] else None
            summaries.append(summary)
    if said and (shot != given or not any(sm.get("model") for sm in summaries)):
        print(said, file=sys.stderr)  # once it rendered: a refusal stays the only line
    typer.echo(json.dumps(summaries[0] if len(summaries) == 1 else summaries, indent=2))


def register(app: typer.Typer) -> None:
    """Adds this package's commands to ``app``."""
    app.command("review")(review)
