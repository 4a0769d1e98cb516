"""The ``tween`` command line. Each package registers its own commands.

Errors the user can act on (:class:`pipeline.errors.TweenError`) print one line on
stderr and exit with status 2; progress goes to stderr, results to stdout.
"""

from __future__ import annotations

import sys

import typer

from pipeline.errors import TweenError

app = typer.Typer(
    name="tween",
    help="Neural motion in-betweening for UsdSkel shots.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)


@app.callback()
def _root() -> None:
    """Neural motion in-betweening for UsdSkel shots."""


def _register() -> None:
    # Command modules import their heavy dependencies inside the commands, so `tween --help`
    # and `tween fill` never import torch.
    from pipeline.bench import cli as bench_cli
    from pipeline.rig import cli as rig_cli
    from pipeline.train import cli as train_cli
    from pipeline.usd import cli as usd_cli
    from render import cli as render_cli
    from workers import cli as workers_cli

    for mod in (bench_cli, usd_cli, train_cli, workers_cli, render_cli, rig_cli):
        mod.register(app)


_register()


def main() -> None:
    try:
        app()
    except TweenError as e:
        print(f"tween: error: {e}", file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt:
        print("tween: interrupted", file=sys.stderr)
        sys.exit(130)


if __name__ == "__main__":
    main()
