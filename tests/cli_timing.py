"""Wall-clock bounds that hold on a loaded machine: measured against the CLI's own start-up.

A bare "< 6 s" fails when pytest-xdist or a busy CI box doubles every process's start-up; the
start-up of ``tween fill --help`` under the same environment and load is the floor every command
pays, so a bound above it stays about the work the test means (for example, no farm started).
"""

from __future__ import annotations

import subprocess
import sys
import time


def cli_floor(env: dict, cwd) -> float:
    """Seconds that ``tween fill --help`` takes here and now (Python, imports, the CLI)."""
    t0 = time.monotonic()
    subprocess.run([sys.executable, "-m", "pipeline.cli", "fill", "--help"], env=env, cwd=cwd,
                   capture_output=True, check=True, timeout=120)  # fmt: skip
    return time.monotonic() - t0
