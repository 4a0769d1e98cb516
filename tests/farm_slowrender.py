"""Imported by a test worker (``--include farm_slowrender``, or the sitecustomize of an embedded
test): a review render that takes a while, and says when it has started.

Every numbered frame waits ``TWEEN_TEST_FRAME_DELAY`` seconds before it is written; the first
one drops a marker ``<process group>.render`` in ``TWEEN_TEST_MARKERS`` (the render's scratch
folder exists from then on). With ``TWEEN_TEST_IGNORE_SOFT=1`` the render ignores the soft time
limit's signal, so that only the hard limit can stop it.
"""

import os
import signal
import time

from render import review

_real_write_png = review.write_png
_real_render = review.render_review


def write_png(path, rows, meta):
    markers = os.environ.get("TWEEN_TEST_MARKERS")
    if markers:
        marker = os.path.join(markers, f"{os.getpgid(0)}.render")
        if not os.path.exists(marker):
            with open(marker, "w") as f:
                f.write(str(os.getpid()))
    time.sleep(float(os.environ.get("TWEEN_TEST_FRAME_DELAY", "0")))
    return _real_write_png(path, rows, meta)


def render_review(*args, **kwargs):
    if os.environ.get("TWEEN_TEST_IGNORE_SOFT"):
        signal.signal(signal.SIGUSR1, signal.SIG_IGN)
    return _real_render(*args, **kwargs)


review.write_png = write_png
review.render_review = render_review
