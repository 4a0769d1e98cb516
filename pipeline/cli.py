"""The ``tween`` command line. Each package registers its own commands.

Errors the user can act on (:class:`pipeline.errors.TweenError`) print one line on
stderr and exit with status 2; progress goes to stderr, results to stdout.
"""

from __future__ import annotations

import sys

import typer

try:  # typer 0.2x carries its own copy of click
    from typer._click.exceptions import BadParameter, ClickException, UsageError
except ImportError:  # older typer uses click itself
    from click.exceptions import BadParameter, ClickException, UsageError

from importlib.metadata import entry_points

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


def _usage_line(e: ClickException) -> str:
    """Click's usage error as one line: the message, with the command it is about."""
    msg = " ".join(e.format_message().split())
    ctx = getattr(e, "ctx", None)
    if isinstance(e, UsageError) and ctx is not None and ctx.parent is not None:
        msg = f"{ctx.info_name}: {msg}"
        if not isinstance(e, BadParameter):
            msg += f" (see `tween {ctx.info_name} --help`)"
    return msg


def main(argv: list[str] | None = None) -> None:
    """The entry point: always exits (0, the command's own status, 2 for errors the user can
    act on, each one line on stderr, or 130 when interrupted)."""
    try:
        # standalone_mode=False: click's usage errors come here instead of printing a usage
        # box, so that a bad option value is one line like every other bad input.
        rc = app(args=argv, prog_name="tween", standalone_mode=False)
    except UsageError as e:
        if type(e).__name__ == "NoArgsIsHelpError":  # `tween` alone: its help, as before
            text = e.format_message()  # (typer's rich help is already printed, text is "")
            if text.strip():
                typer.echo(text)
        else:
            print(f"tween: error: {_usage_line(e)}", file=sys.stderr)
        sys.exit(2)
    except TweenError as e:
        print(f"tween: error: {e}", file=sys.stderr)
        sys.exit(2)
    except ClickException as e:
        print(f"tween: error: {_usage_line(e)}", file=sys.stderr)
        sys.exit(2)
    except (KeyboardInterrupt, typer.Abort):
        print("tween: interrupted", file=sys.stderr)
        sys.exit(130)
    if rc == 130:
        print("tween: interrupted", file=sys.stderr)
    sys.exit(rc if isinstance(rc, int) else 0)


if __name__ == "__main__":
    main()
