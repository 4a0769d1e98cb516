"""Long jobs on the training queue (own app, own time limits and Redis visibility timeout)."""

from __future__ import annotations

import subprocess
import sys

from workers.app import train_app
from workers.errors import JobError


@train_app.task(name="tween.train", bind=True)
def train(self, args: list[str]) -> dict:
    """Runs ``tween train ARGS`` (the training package's own CLI) on this worker."""
    cmd = [sys.executable, "-m", "pipeline.cli", "train", *map(str, args)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        tail = "\n".join(proc.stderr.strip().splitlines()[-5:])
        raise JobError(f"tween train {' '.join(map(str, args))}: exit {proc.returncode}: {tail}")
    return {"stdout": proc.stdout[-4000:]}
