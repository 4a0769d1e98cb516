"""The ``tween`` command line. Each package registers its own commands.

Every command's errors end in one handler (:func:`pipeline.command.run`): one ``tween:
error:`` line and exit status 2 for what the user can act on, a line naming the log for a
bug of ours. Progress goes to stderr, results to stdout.
"""

from __future__ import annotations

from importlib.metadata import entry_points

import typer

from pipeline import command
from pipeline.data.cache_paths import cache_root

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


#: The entry-point group whose ``register(app)`` functions add the commands (setup.py).
COMMANDS = "tween.commands"


def _register() -> None:
    # Each package's command module is named in setup.py's entry points, so this core
    # imports neither the farm nor the renderer; the modules import their heavy
    # dependencies inside the commands (`tween --help` and `tween fill` never import torch).

    found = {ep.name: ep for ep in entry_points(group=COMMANDS)}
    if not found:
        raise SystemExit("tween: error: no commands installed (pip install -e . registers them)")
    for name in ("bench", "fill", "train", "farm", "render", "rig", *sorted(found)):
        ep = found.pop(name, None)
        if ep is not None:
            ep.load()(app)


_register()


def main(argv: list[str] | None = None) -> None:
    """The entry point: always exits (0, the command's own status, 2 for errors the user can
    act on, 1 for a bug of ours, 130 when interrupted)."""
    command.run(app, argv, log_dir=cache_root() / "logs")


if __name__ == "__main__":
    main()
