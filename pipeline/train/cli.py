"""``tween train`` and ``tween export`` (need the ``[train]`` extra: torch).

`tween train`'s flags are made from :class:`pipeline.train.generator_training.TrainConfig` (one flag
per field, its default and help declared there; pipeline/train/recipe.py). That command is
built when `tween train` runs, as it imports torch: `tween --help` and `tween fill` do not.
"""

import typer

from pipeline.train.commands import export
from pipeline.train.recipe import train_command


def register(app: typer.Typer) -> None:
    @app.command(
        context_settings={"ignore_unknown_options": True, "allow_extra_args": True},
        add_help_option=False,
    )
    def train(ctx: typer.Context):
        """Train the path predictor, then the generator, on CPU; or replay a recipe (--recipe NAME)."""

        cmd = train_command()  # its options made from TrainConfig's fields
        with cmd.make_context("train", list(ctx.args), parent=ctx.parent) as sub:
            return cmd.invoke(sub)

    app.command()(export)
