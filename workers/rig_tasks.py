"""Per-rig model training on the farm: ``tween train-rig`` as a task of its own app and queue.

The task runs the training package's own CLI in a subprocess (torch stays out of the
worker process; a crash of the trainer cannot take the worker down) and reports progress in
the task's meta (state ``PROGRESS``): the level group, iteration and overall fraction, parsed
from the trainer's progress bar on stderr. Training checkpoints into ``OUT/checkpoints`` and
resumes from them, so a job that is redelivered (a dead host) or resubmitted after its time
limit carries on where it stopped.
"""

from __future__ import annotations

import os
import re
import select
import signal
import subprocess
import sys
import tempfile
import time

from celery.exceptions import SoftTimeLimitExceeded

from workers import paths as jobpaths
from workers.app import rig_app
from workers.errors import JobError

PROGRESS = "PROGRESS"
#: ``tween train-rig`` options a job may carry (name → CLI flag); anything else is refused.
OPTIONS = {
    "skeleton": "--skeleton",
    "frames": "--frames",
    "fps": "--fps",
    "schedule": "--schedule",
    "iters": "--iters",
    "ratio": "--ratio",
    "contacts": "--contacts",
    "seed": "--seed",
    "threads": "--threads",
    "device": "--device",
    "licence": "--licence",
    "name": "--name",
}
# tqdm's bar of pipeline.rig.train: "levels 3-4/7:  40%|████      | 12/30 [...]"
_BAR = re.compile(r"levels (\d+)-(\d+)/(\d+):\s*\d+%\|[^|]*\|\s*(\d+)/(\d+)")


def train_args(source: str, out: str, options: dict) -> list[str]:
    """The ``tween train-rig`` command line of a job (options checked)."""
    unknown = sorted(set(options) - set(OPTIONS))
    if unknown:
        raise JobError(f"{source}: unknown train-rig option(s): {', '.join(unknown)}")
    args = ["train-rig", str(source), "--out", str(out)]
    for key, flag in OPTIONS.items():
        v = options.get(key)
        if v is not None and v != "":
            args += [flag, str(v)]
    return args


def command(source: str, out: str, options: dict) -> list[str]:
    return [sys.executable, "-m", "pipeline.cli", *train_args(source, out, options)]


def parse_progress(text: str) -> dict | None:
    """The last progress-bar state in ``text`` (stderr of the trainer), or None."""
    found = None
    for m in _BAR.finditer(text):
        first, top, levels, it, iters = map(int, m.groups())
        span = top - first + 1
        frac = (first - 1 + span * it / max(1, iters)) / max(1, levels)
        found = {
            "levels": f"{first}-{top}/{levels}",
            "iteration": it,
            "iterations": iters,
            "fraction": round(min(1.0, frac), 4),
        }
    return found


def check_paths(source: str, out: str, roots) -> None:
    jobpaths.check_under_roots(source, roots, "source")
    jobpaths.check_under_roots(out, roots, "model folder")


@rig_app.task(name="tween.train_rig", bind=True)
def train_rig(self, source: str, out: str, options: dict) -> dict:
    """Trains (and exports) a per-rig model from ``source`` into ``out``."""
    s = rig_app.conf.tween
    check_paths(source, out, s.shot_roots)
    cmd = command(source, out, options)
    env = dict(os.environ)
    threads = str(options.get("threads") or 1)
    env.update(OMP_NUM_THREADS=threads, MKL_NUM_THREADS=threads)
    last: dict | None = None
    tail = ""
    updates = 0
    with tempfile.TemporaryFile() as stdout:
        proc = subprocess.Popen(
            cmd,
            stdout=stdout,
            stderr=subprocess.PIPE,
            stdin=subprocess.DEVNULL,
            env=env,
            start_new_session=True,
        )
        try:
            t_last, pending, fd = 0.0, None, proc.stderr.fileno()
            while True:
                # Wake at least twice a second, so the last state before a long step is reported.
                if select.select([fd], [], [], 0.5)[0]:
                    chunk = os.read(fd, 65536)
                    if not chunk:
                        break
                    tail = (tail + chunk.decode(errors="replace"))[-20000:]
                    p = parse_progress(tail[-4000:])
                    if p and p != last:
                        pending = p
                now = time.monotonic()
                if pending and now - t_last >= 0.2:
                    last, pending, t_last = pending, None, now
                    updates += 1
                    self.update_state(state=PROGRESS, meta={"source": source, "out": out, **last})
            proc.wait()
        except SoftTimeLimitExceeded:
            _stop(proc)
            raise JobError(
                f"{source}: training stopped at its time limit ({s.train_rig_time_limit} s); checkpoints "
                f"are kept in {out}/checkpoints: submit the same job again to resume"
            ) from None
        except BaseException:
            _stop(proc)
            raise
        stdout.seek(0)
        out_text = stdout.read().decode(errors="replace")
    if proc.returncode != 0:
        lines = [ln for ln in re.split(r"[\r\n]+", tail) if ln.strip() and not _BAR.search(ln)]
        msg = lines[-1].strip() if lines else f"exit {proc.returncode}"
        raise JobError(msg.removeprefix("tween: error: "))
    result = {"source": source, "out": out, "stdout": out_text[-2000:], "progress_updates": updates}
    if last:
        result["progress"] = dict(last, fraction=1.0)
    try:
        from pipeline.rig.store import read_rig_json

        info = read_rig_json(out)
        result.update(model=info.name, model_hash=info.hash, fps=info.fps, joints=len(info.names))
    except Exception as e:  # trained with no_export, or the export failed: say so
        result["export"] = str(e)
    return result


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=30)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            proc.wait()
