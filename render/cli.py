"""``tween review``: turntable review media (MP4, frames, contact sheet) for a filled shot."""

from __future__ import annotations

import json
import re

import typer


def _size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m:
        raise typer.BadParameter(f"{text!r}: expected WIDTHxHEIGHT, e.g. 960x540")
    return int(m.group(1)), int(m.group(2))


def _range(text: str | None) -> tuple[float, float] | None:
    if text is None:
        return None
    m = re.fullmatch(r"\s*(-?[\d.]+)\s*[:-]\s*(-?[\d.]+)\s*", text)
    if not m:
        raise typer.BadParameter(f"{text!r}: expected START:END time codes, e.g. 1001:1100")
    return float(m.group(1)), float(m.group(2))


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
    camera: str = typer.Option("turntable", "--camera", help="turntable, front or side."),
    turns: float = typer.Option(1.0, "--turns", help="Camera orbits over the shot (turntable)."),
    ghosts: bool = typer.Option(False, "--ghosts", help="Translucent key poses along the path."),
    no_frames: bool = typer.Option(False, "--no-frames", help="Only the MP4 and the contact sheet."),
    frames: str = typer.Option(None, "--frames", help="Render only time codes START:END."),
) -> None:
    """Renders review media for a filled shot: H.264 MP4, numbered frames, contact sheet."""
    from pathlib import Path

    from render.review import render_review
    from render.scene import list_takes

    w, h = _size(size)
    fr = _range(frames)
    if camera not in ("turntable", "front", "side"):
        raise typer.BadParameter(f"{camera!r}: expected turntable, front or side", param_hint="--camera")
    out_dir = out or str(Path("review") / Path(shot).name.split(".")[0])
    takes = [take]
    if all_takes:
        if take is not None:
            raise typer.BadParameter("give --take N or --all-takes, not both", param_hint="--all-takes")
        takes = (list_takes(shot) if Path(shot).exists() else []) or [None]
    summaries = []
    for t in takes:
        result = render_review(
            shot, out_dir, take=t, size=(w, h), side_by_side=side_by_side, exr=exr, camera=camera, turns=turns,
            ghosts=ghosts, write_frames=not no_frames, frame_range=fr, progress=True,
        )  # fmt: skip
        summary = {k: v for k, v in result.items() if k not in ("frames", "frame_numbers", "timecodes")}
        summary["frame_count"] = len(result["frame_numbers"])
        summary["frames_dir"] = out_dir if result["frames"] else None
        summaries.append(summary)
    typer.echo(json.dumps(summaries[0] if len(summaries) == 1 else summaries, indent=2))


def register(app: typer.Typer) -> None:
    """Adds this package's commands to ``app``."""
    app.command("review")(review)
