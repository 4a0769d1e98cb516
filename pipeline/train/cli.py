"""Commands of this package for the ``tween`` CLI."""

import typer


def register(app: typer.Typer) -> None:
    """Adds this package's commands to ``app``."""
