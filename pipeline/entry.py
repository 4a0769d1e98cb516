"""The ``tween`` executable's first module, kept to the standard library so that it loads at
once: Ctrl-C or SIGTERM while the command line itself loads (about half a second of imports
before :func:`pipeline.command.run` sets its handlers) is one line and status 130, not a
Python traceback. Nothing has been read or written by then.

Both signals are ignored for the process's last moments, once the command has ended and the
exit handlers have run: Python restores their default action as it shuts down, and a Ctrl-C
or SIGTERM while its modules were torn down (a tenth of a second after a publish or a library
build had written everything and said so) killed the process by the signal, with no line, so
that finished output looked interrupted. Until then (the exit handlers, which may wait for
threads or child processes) a signal is still ``tween: interrupted`` and status 130."""

import atexit
import os
import signal
import sys


def _while_loading(signum, frame):
    sys.stderr.write("tween: interrupted\n")
    sys.stderr.flush()
    os._exit(130)  # mid-import: nothing to unwind, and unwinding would print the traceback


def _ignore_at_exit() -> None:
    """The last exit handler: from here on a signal is ignored (Python leaves an ignored
    signal so as it shuts down; a handled one goes back to killing the process)."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)


def main() -> None:
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _while_loading)
    atexit.register(_ignore_at_exit)  # registered first, so it runs last
    from pipeline.cli import main as run

    run()
