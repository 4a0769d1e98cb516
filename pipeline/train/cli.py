"""``tween train`` and ``tween export`` (need the ``[train]`` extra: torch).

`tween train`'s flags are made from :class:`pipeline.train.generator.TrainConfig` (one flag
per field, its default and help declared there; pipeline/train/recipe.py). That command is
built when `tween train` runs, as it imports torch: `tween --help` and `tween fill` do not.
"""

from functools import cache
from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command(
        context_settings={"ignore_unknown_options": True, "allow_extra_args": True},
        add_help_option=False,
    )
    def train(ctx: typer.Context):
        """Train the path predictor, then the generator, on CPU; or replay a recipe (--recipe NAME)."""
        from pipeline.train.recipe import train_command

        cmd = train_command()  # its options made from TrainConfig's fields
        with cmd.make_context("train", list(ctx.args), parent=ctx.parent) as sub:
            return cmd.invoke(sub)

    app.command()(export)


def export(
    run: Path = typer.Argument(..., help="Run folder written by `tween train`."),
    out: Path = typer.Option(..., help="Model folder to write (ONNX files + model.json)."),
    name: str = typer.Option(None, help="Model name (default: the folder name)."),
    root: str = typer.Option("generator", help="Root path source at inference: generator or path."),
    pad: str = typer.Option(
        "hold-key", help="Pad layout at inference: hold-key (the last padded frame a key), end, front."
    ),
    pad_tail: int = typer.Option(16, help="Frames held after the last key at least, when padding."),
    min_window: int = typer.Option(64, help="Shortest padded window, frames."),
    feet_anchor: bool = typer.Option(True, help="Lock contacts that hold a key at the key's foot position."),
    feet_orient: bool = typer.Option(True, help="Locked feet hold their orientation too (toes stay put)."),
):
    """Export both networks to ONNX and check onnxruntime against torch."""
    from pipeline.train.export import export as do_export
    from pipeline.train.export import verify

    settings = {
        "root": root,
        "pad": pad,
        "pad_tail": pad_tail,
        "min_window": min_window,
        "feet_anchor": feet_anchor,
        "feet_orient": feet_orient,
    }
    meta = do_export(run, out, name or out.name, settings)
    err = verify(run, out)
    typer.echo(f"{out}: model {meta['name']} hash {meta['hash']}; max |onnx - torch| = {err:.2e}")


@cache
def export_command():
    """`tween export` as a click command of its own (the recipe runner calls it in process)."""
    sub = typer.Typer(add_completion=False, pretty_exceptions_enable=False)
    sub.command("export")(export)
    return typer.main.get_command(sub)
