"""Per-rig model training on the farm: ``tween train-rig`` as a task of its own app and queue.

The task runs the training package's own CLI in a subprocess (torch stays out of the
worker process; a crash of the trainer cannot take the worker down) and reports progress in
the task's meta (state ``PROGRESS``). The trainer sends its progress as structured records
(``pipeline.rig.progress.Progress``) over a pipe of their own (``--progress-fd``); each
becomes the meta as it is (``asdict``) plus the keys ``tween status`` shows (``levels``,
``iteration``, ``iterations``, ``fraction``). Nothing reads the text of a progress bar; stderr
is kept for the error message only. Training checkpoints into ``OUT/checkpoints`` and resumes
from them, so a job that is redelivered (a dead host) or resubmitted after its time limit
carries on where it stopped.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict

from celery.exceptions import SoftTimeLimitExceeded

from pipeline.rig.options import FLAGS, command_args
from pipeline.rig.progress import JsonLinesReader, Progress
from pipeline.rig.store import read_rig_json
from pipeline.staging import partial_folder
from workers import paths as jobpaths
from workers.app import rig_app
from workers.errors import JobError

PROGRESS = "PROGRESS"
#: ``tween train-rig`` options a job may carry (name → CLI flag); anything else is refused.
#: A job's option names and their ``tween train-rig`` flags (declared in pipeline.rig.options).
OPTIONS = FLAGS
#: Least seconds between two state updates (the backend is written at most this often).
UPDATE_EVERY = 0.2


def train_args(source: str, out: str, options: dict) -> list[str]:
    """The ``tween train-rig`` command line of a job (options checked)."""
    try:
        flags = command_args(options)
    except ValueError as e:
        raise JobError(f"{source}: {e}") from None
    return ["train-rig", str(source), "--out", str(out), *flags]


def command(source: str, out: str, options: dict, progress_fd: int | None = None) -> list[str]:
    cmd = [sys.executable, "-m", "pipeline.cli", *train_args(source, out, options)]
    if progress_fd is not None:
        cmd += ["--progress-fd", str(progress_fd)]
    return cmd


def progress_meta(record: Progress) -> dict:
    """A record as task meta: its fields (``asdict``) and the keys ``tween status`` and
    ``submit-train-rig --wait`` show: ``levels`` ("3-4/7"), ``iteration``/``iterations``
    (within that group of levels) and ``fraction`` (of the whole run)."""
    meta = asdict(record)
    meta["group_levels"] = list(record.group_levels)
    if record.group_levels:
        meta["levels"] = f"{record.group_levels[0]}-{record.group_levels[-1]}/{record.n_levels}"
    meta["iteration"], meta["iterations"] = record.stage_step, record.stage_steps
    meta["fraction"] = round(record.fraction, 4)
    return meta


def check_paths(source: str, out: str, roots) -> None:
    jobpaths.check_under_roots(source, roots, "source")
    jobpaths.check_under_roots(out, roots, "model folder")


@rig_app.task(name="tween.train_rig", bind=True)
def train_rig(self, source: str, out: str, options: dict) -> dict:
    """Trains (and exports) a per-rig model from ``source`` into ``out``."""
    return run_train_rig(self, source, out, options)


def _follow(proc: subprocess.Popen, read_fd: int, report) -> tuple[Progress | None, bytes]:
    """Reads the training's progress records from ``read_fd`` (each new one to ``report``, at
    most every UPDATE_EVERY s, the final one always) and keeps the tail of its stderr, until
    it exits; returns the last record and that tail."""
    last: Progress | None = None
    tail = b""
    reader, pending, t_last = JsonLinesReader(), None, 0.0
    err_fd = proc.stderr.fileno()
    open_fds = [read_fd, err_fd]
    while open_fds:
        # Wake at least twice a second, so the last state before a long step is reported.
        for fd in select.select(open_fds, [], [], 0.5)[0]:
            chunk = os.read(fd, 65536)
            if not chunk:
                open_fds.remove(fd)
            elif fd == err_fd:
                tail = (tail + chunk)[-20000:]
            else:
                for record in reader.feed(chunk):
                    if record != last:
                        pending = record
        now = time.monotonic()
        if pending is not None and now - t_last >= UPDATE_EVERY:
            last, pending, t_last = pending, None, now
            report(last)
    proc.wait()
    if pending is not None:  # the final record, whatever the throttle held back
        last = pending
        report(last)
    return last, tail


def run_train_rig(task, source: str, out: str, options: dict) -> dict:
    """The body of :func:`train_rig`; ``task`` is the bound task (``task.update_state`` gets
    the progress)."""
    s = rig_app.conf.tween
    check_paths(source, out, s.shot_roots)
    env = dict(os.environ)
    threads = str(options.get("threads") or 1)
    env.update(OMP_NUM_THREADS=threads, MKL_NUM_THREADS=threads)
    updates = 0

    def report(record: Progress) -> None:
        nonlocal updates
        updates += 1
        task.update_state(state=PROGRESS, meta={"source": source, "out": out, **progress_meta(record)})

    read_fd, write_fd = os.pipe()
    with tempfile.TemporaryFile() as stdout:
        try:
            proc = subprocess.Popen(
                command(source, out, options, progress_fd=write_fd),
                stdout=stdout,
                stderr=subprocess.PIPE,
                stdin=subprocess.DEVNULL,
                env=env,
                start_new_session=True,
                pass_fds=(write_fd,),
            )
        finally:
            os.close(write_fd)  # the child holds its copy: EOF here when it exits
        try:
            last, tail = _follow(proc, read_fd, report)
        except SoftTimeLimitExceeded:
            _stop(proc)
            raise JobError(
                f"{source}: training stopped at its time limit ({s.train_rig_time_limit} s); checkpoints "
                f"are kept in {partial_folder(out)}/checkpoints: submit the same job "
                "again to resume"
            ) from None
        except BaseException:
            _stop(proc)
            raise
        finally:
            os.close(read_fd)
        stdout.seek(0)
        out_text = stdout.read().decode(errors="replace")
    if proc.returncode != 0:
        lines = [ln.strip() for ln in tail.decode(errors="replace").splitlines() if ln.strip()]
        msg = lines[-1] if lines else f"exit {proc.returncode}"
        raise JobError(msg.removeprefix("tween: error: "))
    result = {"source": source, "out": out, "stdout": out_text[-2000:], "progress_updates": updates}
    if last is not None:
        result["progress"] = dict(progress_meta(last), fraction=1.0)
    try:
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
