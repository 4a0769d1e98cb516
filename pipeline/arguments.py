"""argparse for the ``python -m`` entry points (benches, data tools): a bad argument is a
:class:`~pipeline.errors.TweenError`, so it is one ``tween: error:`` line and exit 2 under
``pipeline.command.run_main``, not argparse's usage box and a second line."""

from __future__ import annotations

import argparse

from pipeline.errors import TweenError


class Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are raised as TweenError, naming the program."""

    def error(self, message: str):
        raise TweenError(f"{self.prog}: {message}")
