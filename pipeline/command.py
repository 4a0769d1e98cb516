"""The one error handler every ``tween`` entry point runs its commands through.

Errors the user can act on (:class:`pipeline.errors.TweenError` from any layer, click's usage
errors, an operating-system error on a named file: disk full, read-only, permission) print
one ``tween: error:`` line on stderr and exit with status 2. Anything else is a bug of ours:
one line that says so and names the log file holding the traceback, exit status 1.
"""

from __future__ import annotations

import datetime
import os
import signal
import sys
import threading
import traceback
from contextlib import contextmanager
from pathlib import Path

import typer

try:  # typer 0.2x carries its own copy of click
    from typer._click.exceptions import BadParameter, ClickException, UsageError
except ImportError:  # older typer uses click itself
    from click.exceptions import BadParameter, ClickException, UsageError

from pipeline.errors import DISK_FULL, TweenError, printable


def _usage_line(e: ClickException) -> str:
    """Click's usage error as one line: the message, with the command it is about."""
    msg = " ".join(e.format_message().split())
    ctx = getattr(e, "ctx", None)
    if isinstance(e, UsageError) and ctx is not None and ctx.parent is not None:
        msg = f"{ctx.info_name}: {msg}"
        if not isinstance(e, BadParameter):
            msg += f" (see `tween {ctx.info_name} --help`)"
    return msg


def _os_error_line(e: OSError) -> str | None:
    """An operating-system error on a file as one line naming it (``None``: no file named,
    so not something this handler can word; the caller treats it as a bug)."""
    if not e.filename:
        if e.errno in DISK_FULL:  # a write that ran out of room names no file
            return f"{e.strerror}: the disk (or the file-size limit) is full; free space and run again"
        return None
    where = f"{e.filename} -> {e.filename2}" if e.filename2 else str(e.filename)
    return f"{where}: {e.strerror or e}"


def _shown(line: str) -> str:
    """``line`` as stderr can always write it, on one line: a path that is not UTF-8
    (surrogates) escaped, and control characters (a file name holding a newline)."""
    return printable(line.encode("utf-8", "backslashreplace").decode("utf-8"))


def _log_bug(e: BaseException, logs: Path | None, argv: list[str] | None = None) -> str:
    """Writes the traceback of an unexpected error to a log file in ``logs``; returns where."""
    if logs is None:
        sys.stderr.write("".join(traceback.format_exception(e)))
        return "above"
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    path = logs / f"tween-{stamp}-{os.getpid()}.log"
    args = sys.argv[1:] if argv is None else argv
    text = f"tween {' '.join(map(str, args))}\n\n" + "".join(traceback.format_exception(e))
    try:
        logs.mkdir(parents=True, exist_ok=True)
        path.write_text(text, errors="backslashreplace")  # a path that is not UTF-8 (surrogates)
    except OSError:  # no log either: the traceback goes to stderr after all
        sys.stderr.write(text)
        return "above"
    return str(path)


def _bug_line(e: BaseException, logs: Path | None, argv: list[str] | None = None) -> str:
    first = (str(e).strip().splitlines() or [""])[0][:300]
    what = f"{type(e).__name__}: {first}" if first else type(e).__name__
    return (
        f"tween: internal error (a bug in usd-tween, not in your input): {what}; "
        f"the traceback is in {_log_bug(e, logs, argv)}"
    )


#: How long an interrupt that lands inside an import waits before it is tried again (s).
RETRY_S = 0.05


def _importing(frame) -> bool:
    """Whether ``frame`` runs inside a module's import."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def _interrupt(signum, frame):
    """SIGINT and SIGTERM while a command runs: KeyboardInterrupt, except inside an import.
    USD's module loader (``Tf.PreparePythonModule``, run by ``from pxr import ...``) catches
    what is raised there and prints it, so the interrupt was lost (a fill interrupted as it
    loaded USD ran on to write its layer and exit 0) or left a module half made (a later
    internal error). There the signal is sent again a moment later, until it lands outside."""
    if _importing(frame):
        again = threading.Timer(RETRY_S, os.kill, (os.getpid(), signum))
        again.daemon = True  # never keeps a finished command's process alive
        again.start()
        return
    raise KeyboardInterrupt()


@contextmanager
def _signals_as_interrupt():
    """SIGTERM (a farm's or a shell's kill) unwinds like Ctrl-C while a command runs, so that
    what it half wrote is removed (a first library build, staged model folders) instead of the
    process dying where it stands; neither is raised inside an import (:func:`_interrupt`).
    Only from the main thread, where Python runs handlers."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {sig: signal.signal(sig, _interrupt) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def run(app: typer.Typer, argv: list[str] | None = None, prog: str = "tween", log_dir: Path | None = None):
    """Runs ``app`` and exits: 0 or the command's own status, 2 for an error the user can act
    on, 1 for a bug of ours (its traceback written under ``log_dir``), 130 when interrupted."""
    try:
        # standalone_mode=False: click's usage errors come here instead of printing a usage
        # box, so that a bad option value is one line like every other bad input.
        with _signals_as_interrupt():
            rc = app(args=argv, prog_name=prog, standalone_mode=False)
    except UsageError as e:
        if type(e).__name__ == "NoArgsIsHelpError":  # `tween` alone: its help, as before
            text = e.format_message()  # (typer's rich help is already printed, text is "")
            if text.strip():
                typer.echo(text)
        else:
            print(_shown(f"tween: error: {_usage_line(e)}"), file=sys.stderr)
        sys.exit(2)
    except TweenError as e:
        print(_shown(f"tween: error: {e}"), file=sys.stderr)
        sys.exit(2)
    except ClickException as e:
        print(_shown(f"tween: error: {_usage_line(e)}"), file=sys.stderr)
        sys.exit(2)
    except (KeyboardInterrupt, typer.Abort) as e:
        if isinstance(e.__context__, EOFError):  # click turns an EOFError into Abort
            print(_bug_line(e.__context__, log_dir, argv), file=sys.stderr)
            sys.exit(1)
        print("tween: interrupted", file=sys.stderr)
        sys.exit(130)
    except OSError as e:
        line = _os_error_line(e)
        if line is None:
            print(_bug_line(e, log_dir, argv), file=sys.stderr)
            sys.exit(1)
        print(_shown(f"tween: error: {line}"), file=sys.stderr)
        sys.exit(2)
    except Exception as e:
        print(_bug_line(e, log_dir, argv), file=sys.stderr)
        sys.exit(1)
    if rc == 130:  # typer's own status for an interrupt it caught
        print("tween: interrupted", file=sys.stderr)
    sys.exit(rc if isinstance(rc, int) else 0)


def run_main(main, argv: list[str] | None = None, log_dir: Path | None = None):
    """Runs an argparse entry point ``main(argv) -> int`` (the benches' ``python -m``
    commands) under the same rules as :func:`run` and exits: one ``tween: error:`` line and 2
    for an error the user can act on, 1 for a bug of ours, 130 when interrupted."""
    try:
        rc = main(argv)
    except TweenError as e:
        print(_shown(f"tween: error: {e}"), file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt:
        print("tween: interrupted", file=sys.stderr)
        sys.exit(130)
    except OSError as e:
        line = _os_error_line(e)
        print(_shown(f"tween: error: {line}") if line else _bug_line(e, log_dir, argv), file=sys.stderr)
        sys.exit(2 if line else 1)
    except Exception as e:
        print(_bug_line(e, log_dir, argv), file=sys.stderr)
        sys.exit(1)
    sys.exit(rc if isinstance(rc, int) else 0)
