"""``tween train-rig`` (needs the ``[train]`` extra) and ``tween rig-extract``."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import typer

from pipeline import command
from pipeline.atomic import naming, replacing
from pipeline.data.cache_paths import cache_root
from pipeline.errors import TweenError
from pipeline.outputs import refuse_under_a_file
from pipeline.rig.options import TrainRigOptions, with_train_rig_options
from pipeline.rig.progress import JsonLinesWriter, ProgressBar
from pipeline.staging import StagedFolder, refuse_read_only


@with_train_rig_options
def train_rig(
    source: Path = typer.Argument(
        ..., help="The reference clip: a USD shot or a BVH (.bvh/.bvh.gz), or an .npz from rig-extract."
    ),
    out: Path = typer.Option(
        ...,
        "--out",
        help="Model folder, written only when complete (training checkpoints in "
        ".OUT.partial/checkpoints until then; re-running resumes).",
    ),
    checkpoints: Path = typer.Option(None, help="Checkpoint folder (default OUT/checkpoints)."),
    no_export: bool = typer.Option(False, help="Only train; do not write ONNX files and rig.json."),
    progress_fd: int = typer.Option(
        None,
        "--progress-fd",
        hidden=True,
        help="Write progress records as JSON lines to this open file descriptor instead of a bar "
        "on stderr (the farm's channel; pipeline.rig.progress).",
    ),
    opts: TrainRigOptions = None,
):
    """Train a per-rig GANimator on one clip, then export it (ONNX per level + rig.json + card)."""
    from pipeline.rig.source import parse_frames
    from pipeline.rig.train import TrainConfig

    o = opts.check()
    refuse_under_a_file(out)
    # Refuses a finished model in --out before anything is read or written; the new
    # model is made beside it and moved into place when complete (pipeline.staging).
    stage = StagedFolder(out, o.force, what="rig model")
    cfg = TrainConfig(
        source=str(source),
        out=str(stage.work),
        skeleton=o.skeleton,
        frames=parse_frames(o.frames),
        fps=o.fps,
        schedule=o.schedule,
        iters=o.iters,
        ratio=o.ratio,
        contacts=o.contact_joints(),
        seed=o.seed,
        threads=o.threads,
        device=o.device,
        licence=o.licence or _guess_licence(source),
        credit=o.credit or _guess_credit(source),
        name=o.name or out.resolve().name,
        checkpoints=str(checkpoints) if checkpoints else None,
    )
    tr = _train_shown(cfg, progress_fd)
    if no_export:
        typer.echo(f"{tr.ckpt_dir}  (trained; run again without --no-export to export into {out})")
        return
    from pipeline.rig.export import export

    meta = export(tr, stage.work, dest=out)
    stage.commit()
    typer.echo(f"{out}  ({meta['name']}, hash {meta['hash']}, {len(meta['levels'])} levels)")


def rig_extract(
    source: Path = typer.Argument(..., help="A USD shot or a BVH."),
    out: Path = typer.Argument(..., help="The .npz to write (for hosts without usd-core or the data)."),
    skeleton: str = typer.Option(None, help="USD: the Skeleton prim path."),
    frames: str = typer.Option(None, help="START:STOP frame indices."),
    force: bool = typer.Option(False, "--force", help="Replace an existing OUT."),
):
    """Save a reference clip as a self-contained .npz that `train-rig` reads."""
    from pipeline.rig.source import load_rig_source, parse_frames, save_npz

    if skeleton is not None and not skeleton.strip():  # read as "not given" before
        raise TweenError(f"--skeleton {skeleton!r}: empty; leave it out for the skeleton with most joints")
    if out.suffix.lower() != ".npz":
        raise TweenError(f"{out}: OUT must name an .npz file")
    if out.is_dir():
        raise TweenError(f"{out}: is a folder; OUT names the .npz file to write")
    if out.exists() and not force:
        raise TweenError(f"{out}: exists; give --force to replace it")
    if out.exists() and out.resolve() == source.resolve():
        raise TweenError(f"{out}: is the source clip; write the .npz elsewhere")
    if not out.parent.is_dir():
        raise TweenError(f"{out.parent}: no such folder for OUT")
    refuse_read_only(out, "OUT")
    motion = load_rig_source(source, skeleton, parse_frames(frames))
    with naming(out), replacing(out, suffix=".npz") as tmp:  # an interrupted write leaves OUT as it was
        save_npz(motion, tmp)
    typer.echo(f"{out}  ({len(motion)} frames at {motion.fps:g} fps, {len(motion.skeleton)} joints)")


def register(app: typer.Typer) -> None:
    """Adds this package's commands to ``app``."""
    app.command("train-rig")(train_rig)
    app.command("rig-extract")(rig_extract)


def _train_shown(cfg, progress_fd: int | None):
    """Runs ``train(cfg)`` with its progress records shown: a bar per group of levels on stderr,
    or JSON lines on ``progress_fd`` for a reader such as the farm's task."""

    from pipeline.rig.train import train

    if progress_fd is None:
        show = ProgressBar(sys.stderr)
    else:
        try:
            show = JsonLinesWriter(os.fdopen(progress_fd, "w", buffering=1))
        except OSError as e:
            raise TweenError(f"--progress-fd {progress_fd}: {e.strerror}") from None
    with show:
        return train(cfg, on_progress=show)


def _guess_credit(source: Path) -> str | None:
    s = str(source).lower()
    if "elephantwithmonochord" in s:
        return (
            '"Songs of Cultures – Vietnamese Elephant with Monochord" by A.MUSE – Interactive Design '
            "Studio (https://amuse.vision), USDZ version by Felix Herbst / prefrontal cortex, "
            "CC BY-SA 4.0 (http://creativecommons.org/licenses/by-sa/4.0/)"
        )
    if "bandai" in s:
        return "Bandai Namco Research Motion Dataset (Kobayashi et al. 2023), CC BY-NC 4.0"
    return None


def _guess_licence(source: Path) -> str:
    s = str(source).lower()
    if "elephantwithmonochord" in s:
        return "CC BY-SA 4.0"
    if "bandai" in s:
        return "CC BY-NC 4.0"
    return "unknown (set --licence)"


def main() -> None:
    """``python -m pipeline.rig.cli`` — these commands alone, for hosts without the farm,
    renderer or usd-core (e.g. a GPU box training from an .npz)."""

    app = typer.Typer(
        name="tween-rig", no_args_is_help=True, pretty_exceptions_enable=False, add_completion=False
    )
    register(app)
    command.run(app, prog="tween-rig", log_dir=cache_root() / "logs")


if __name__ == "__main__":
    main()
