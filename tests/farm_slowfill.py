"""Imported by a test worker (``tween worker --include farm_slowfill``): a fill that takes a while.

Each take first drops a marker named after the worker's process group (so the test knows
which host to kill) and then sleeps ``TWEEN_TEST_FILL_DELAY`` seconds before the real fill.
"""

import os
import time

from pipeline.fill import api as fill

_real_fill_take = fill.fill_take


def fill_take(shot, opts, take, work_dir):
    markers = os.environ.get("TWEEN_TEST_MARKERS")
    if markers:
        with open(os.path.join(markers, f"{os.getpgid(0)}.take{take}"), "w") as f:
            f.write(str(os.getpid()))
    time.sleep(float(os.environ.get("TWEEN_TEST_FILL_DELAY", "0")))
    return _real_fill_take(shot, opts, take, work_dir)


fill.fill_take = fill_take
