"""How often a progress bar on stderr redraws: often on a terminal, rarely in a log file.

tqdm redraws every 0.1 s; a terminal shows one line, but a farm worker's or a nohup'd run's log
file keeps every redraw (a 13-minute fine-tune wrote thousands of them). Bars pass
``mininterval=interval()``."""

from __future__ import annotations

import sys

#: Seconds between redraws when stderr is not a terminal (a log file, a pipe).
LOG_INTERVAL = 30.0
#: Seconds between redraws on a terminal (tqdm's own default).
TERMINAL_INTERVAL = 0.1


def interval(stream=None) -> float:
    """Seconds between a bar's redraws on ``stream`` (default: stderr)."""
    stream = sys.stderr if stream is None else stream
    try:
        return TERMINAL_INTERVAL if stream.isatty() else LOG_INTERVAL
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return LOG_INTERVAL
