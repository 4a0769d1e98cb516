"""Progress bars redraw often on a terminal and rarely in a log file (pipeline.progress)."""

import os
import time

from tqdm import tqdm

from pipeline.progress import LOG_INTERVAL, TERMINAL_INTERVAL, interval


def test_a_terminal_redraws_often_and_a_log_file_rarely(tmp_path):
    primary, replica = os.openpty()  # a real terminal
    try:
        with os.fdopen(replica, "w", closefd=False) as tty:
            assert tty.isatty() and interval(tty) == TERMINAL_INTERVAL
    finally:
        os.close(primary)
        os.close(replica)
    with open(tmp_path / "log", "w") as log:
        assert interval(log) == LOG_INTERVAL
        # A second of work in 200 steps: a line at the start and at the end, where tqdm's own
        # 0.1 s writes about twelve (a file gets each redraw as a line of its own).
        for _ in tqdm(range(200), file=log, mininterval=interval(log)):
            time.sleep(0.005)
    redraws = [ln for ln in (tmp_path / "log").read_text().splitlines() if "%|" in ln]
    assert 1 <= len(redraws) <= 3, redraws


def test_a_stream_without_isatty_counts_as_a_log():
    class Closed:
        def isatty(self):
            raise ValueError("I/O operation on closed file")

    assert interval(object()) == LOG_INTERVAL and interval(Closed()) == LOG_INTERVAL
