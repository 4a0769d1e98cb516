"""``tween export`` as a command of its own: registered by the CLI (pipeline/train/cli.py)
and run in process by the recipe runner (pipeline/train/recipe.py)."""

from functools import cache
from pathlib import Path

import typer

from pipeline.errors import TweenError
from pipeline.options import path_like
from pipeline.outputs import refuse_under_a_file
from pipeline.staging import StagedFolder


def _check_options(root: str, pad: str, pad_tail: int, min_window: int, name: str | None) -> None:
    """`tween export`'s options, before anything is read or written."""
    from pipeline.infer.folder import FIXED, PAD_MAX

    for flag, value in (("--root", root), ("--pad", pad)):
        if value != FIXED[flag[2:]]:
            raise TweenError(f"{flag} {value!r}: this release fills with {FIXED[flag[2:]]!r} only")
    for flag, value in (("--pad-tail", pad_tail), ("--min-window", min_window)):
        if not 0 <= value <= PAD_MAX:
            raise TweenError(f"{flag} {value}: must be 0 to {PAD_MAX} frames (the fill's window grows by it)")
    # --name: not empty, not a path (as train-rig).
    if name is not None and (not name.strip() or path_like(name)):
        raise TweenError(f"--name {name!r}: a model name, not a path or nothing")


def export(
    run: Path = typer.Argument(..., help="Run folder written by `tween train`."),
    out: Path = typer.Option(..., help="Model folder to write (ONNX files + model.json)."),
    name: str = typer.Option(None, help="Model name (default: the folder name)."),
    root: str = typer.Option("generator", help="Root path source at inference: generator (the only one)."),
    pad: str = typer.Option(
        "hold-key", help="Pad layout at inference: hold-key (the last padded frame a key; the only one)."
    ),
    pad_tail: int = typer.Option(16, help="Frames held after the last key at least, when padding."),
    min_window: int = typer.Option(64, help="Shortest padded window, frames."),
    feet_anchor: bool = typer.Option(True, help="Lock contacts that hold a key at the key's foot position."),
    feet_orient: bool = typer.Option(True, help="Locked feet hold their orientation too (toes stay put)."),
    force: bool = typer.Option(
        False, "--force", help="Replace the model in --out (it stays in use until the new one is verified)."
    ),
    familiar_credit: bool = typer.Option(
        None,
        "--familiar-credit/--no-familiar-credit",
        help="Whether the trusted fill leans to this network on keys like its training data (docs/trust.md). "
        "Default: not for a fine-tune on --data takes (nothing measured its lead on them), yes otherwise.",
    ),
):
    """Export both networks to ONNX and check onnxruntime against torch."""
    from pipeline.train.export import export as do_export
    from pipeline.train.export import verify

    _check_options(root, pad, pad_tail, min_window, name)
    if not (run / "generator.pt").is_file():
        raise TweenError(f"{run}: no generator.pt here (give the run folder that `tween train --out` wrote)")
    refuse_under_a_file(out)
    stage = StagedFolder(out, force)  # a finished model in --out is refused before anything is written

    settings = {
        "root": root,
        "pad": pad,
        "pad_tail": pad_tail,
        "min_window": min_window,
        "feet_anchor": feet_anchor,
        "feet_orient": feet_orient,
        "familiar_credit": familiar_credit,
    }
    try:
        meta = do_export(run, stage.make(), name or out.resolve().name, settings)
        err = verify(run, stage.work)
        if not err < float("inf"):
            raise TweenError(
                f"{run}: onnxruntime's output is not a finite number where torch's is; nothing was exported"
            )
    except OSError as e:
        stage.discard()
        raise _in_out(e, stage.work, out) from None
    except BaseException:
        stage.discard()  # a failed export leaves --out as it was
        raise
    stage.commit()
    typer.echo(
        f"{out}: model {meta['name']} hash {meta['hash']}; onnx and torch agree within {err:.2e} (export.verify)"
    )


def _in_out(e: OSError, work: Path, out: Path) -> Exception:
    """An OSError on a file of the model being made (a full disk) as one line naming --out, not
    the hidden folder it is made in; any other as it is."""
    try:
        rel = Path(e.filename).relative_to(work)
    except (TypeError, ValueError):
        return e
    return TweenError(f"{out}: cannot write the new model's {rel}: {e.strerror or e}; --out is as it was")


@cache
def export_command():
    """`tween export` as a click command of its own (the recipe runner calls it in process)."""
    sub = typer.Typer(add_completion=False, pretty_exceptions_enable=False)
    sub.command("export")(export)
    return typer.main.get_command(sub)
