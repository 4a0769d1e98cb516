"""The ``tween`` executable's first module, kept to the standard library so that it loads at
once: Ctrl-C or SIGTERM while the command line itself loads (about half a second of imports
before :func:`pipeline.command.run` sets its handlers) is one line and status 130, not a
Python traceback. Nothing has been read or written by then."""

import os
import signal
import sys


def _while_loading(signum, frame):
    sys.stderr.write("tween: interrupted\n")
    sys.stderr.flush()
    os._exit(130)  # mid-import: nothing to unwind, and unwinding would print the traceback


def main() -> None:
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _while_loading)
    from pipeline.cli import main as run

    run()
