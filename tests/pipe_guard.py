"""A call that may block reading a pipe, for the tests that a pipe where a file is read is
refused at once: the test fails, rather than hangs, where it blocks."""

from __future__ import annotations

import os
import threading

import pytest


def within(fn, fifos=(), seconds: float = 20.0):
    """What ``fn()`` returned or raised, failing the test if it blocks past ``seconds``: a
    reader blocked on one of ``fifos`` is then let go (a writer opened and closed), so no
    thread is left behind."""
    done: dict = {}

    def run():
        try:
            done["value"] = fn()
        except BaseException as e:  # noqa: BLE001 - handed to the test
            done["error"] = e

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(seconds)
    if t.is_alive():
        for f in fifos:
            try:
                os.close(os.open(f, os.O_WRONLY | os.O_NONBLOCK))
            except OSError:
                pass
        t.join(5)
        pytest.fail(f"blocked for over {seconds:.0f} s reading {', '.join(map(str, fifos))}")
    if "error" in done:
        raise done["error"]
    return done.get("value")
