"""Long jobs on the training queue (own app, own time limits and Redis visibility timeout)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tempfile

from celery.exceptions import SoftTimeLimitExceeded

from pipeline.library.options import LOCK_WAIT_S, MAX_LOCK_WAIT_S, command_args
from workers.app import train_app
from workers.errors import JobError
from workers.limits import train_limit_message


@train_app.task(name="tween.train", bind=True)
def train(self, args: list[str]) -> dict:
    """Runs ``tween train ARGS`` (the training package's own CLI) on this worker."""
    cmd = [sys.executable, "-m", "pipeline.cli", "train", *map(str, args)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        tail = "\n".join(proc.stderr.strip().splitlines()[-5:])
        raise JobError(f"tween train {' '.join(map(str, args))}: exit {proc.returncode}: {tail}")
    return {"stdout": proc.stdout[-4000:]}


#: pipeline.library.cli.PROGRESS_LINE, as read back.
_PROGRESS = re.compile(r"^tween: library progress (\d+)/(\d+)")


def farm_lock_wait(soft_limit: float | None) -> float:
    """Seconds a farm build waits for another build of its library to finish: half its soft
    time limit (the other half for its own build), from LOCK_WAIT_S to MAX_LOCK_WAIT_S. With
    `tween library build`'s own 300 s, a build queued behind another of the same library
    failed after 5 minutes, where the farm is meant to queue it."""
    if not soft_limit:
        return LOCK_WAIT_S
    return float(min(MAX_LOCK_WAIT_S, max(LOCK_WAIT_S, soft_limit / 2)))


@train_app.task(name="tween.library_build", bind=True)
def library_build(self, folder: str, out: str, options: dict) -> dict:
    """Runs ``tween library build FOLDER --out OUT`` on this worker (a subprocess, so that a
    take that crashes the reader fails this job only); its paths are checked against the
    worker's own shot roots first. Returns the build's summary (takes, frames, hours, hash)."""
    from workers.app import app as fill_app
    from workers.paths import check_takes_under_roots, check_under_roots

    roots = fill_app.conf.tween.shot_roots
    folder = check_under_roots(folder, roots, "takes folder")
    out = check_under_roots(out, roots, "library")
    check_takes_under_roots(folder, roots)
    cmd = [sys.executable, "-m", "pipeline.cli", "library", "build", folder, "--out", out, "--no-progress"]
    cmd += command_args(options)
    cmd += ["--lock-wait", f"{farm_lock_wait(train_app.conf.task_soft_time_limit):g}"]
    meta = {"stage": "library build", "source": folder, "out": out}
    self.update_state(state="STARTED", meta=meta)
    tail: list[str] = []
    with tempfile.TemporaryFile("w+") as stdout:
        proc = subprocess.Popen(cmd + ["--progress-lines"], stdout=stdout, stderr=subprocess.PIPE, text=True)
        try:
            for line in proc.stderr:  # progress lines become the task's state; the rest is kept for errors
                m = _PROGRESS.match(line)
                if m:
                    self.update_state(state="PROGRESS", meta=meta | {"done": int(m[1]), "total": int(m[2])})
                else:
                    tail = (tail + [line.rstrip()])[-20:]
        except SoftTimeLimitExceeded:  # the build stops with the task, and says which limit
            proc.kill()
            proc.wait()
            raise JobError(
                train_limit_message(f"library build of {folder}", "train_time_limit", train_app.conf.tween)
            ) from None
        proc.wait()
        stdout.seek(0)
        text = stdout.read()
    if proc.returncode != 0:
        lines = [ln for ln in tail if ln.startswith("tween: error:")]
        why = lines[-1].removeprefix("tween: error: ") if lines else "\n".join(tail[-3:])
        raise JobError(f"tween library build {folder}: {why}")
    return json.loads(text)
