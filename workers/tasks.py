"""The stages of a shot's fill job. They pass file paths and small JSON, never arrays.

Each stage is a thin wrapper over :mod:`pipeline.fill` (looked up at call time, so the same
functions serve Celery, a direct in-process run and any other farm adapter). Errors are
sorted in one place: transient I/O and connection errors retry with back-off; anything else
(a bad shot above all) fails the job at once with its message stored on the task.
"""

from __future__ import annotations

import errno
import os
import shutil
from contextlib import contextmanager

from celery import Task
from celery.exceptions import SoftTimeLimitExceeded
from celery.signals import worker_init, worker_process_init

from pipeline.errors import TweenError
from pipeline.fill import api as fill
from pipeline.fill.api import FillOptions
from workers import paths as jobpaths
from workers import runtime
from workers.app import app
from workers.errors import JobError, TransientError
from workers.limits import soft_limit_error

# errnos that mean "try again later" on shared storage (NFS, SMB) or a busy host; anything
# else, FileNotFoundError above all, is the job's own fault and is not retried.
TRANSIENT_ERRNOS = {
    errno.EAGAIN,
    errno.EBUSY,
    errno.EINTR,
    errno.ETIMEDOUT,
    errno.ESTALE,
    errno.ECONNRESET,
    errno.ECONNREFUSED,
    errno.ECONNABORTED,
    errno.EHOSTUNREACH,
    errno.ENETUNREACH,
    errno.EIO,
}


@contextmanager
def _sorted_errors(shot: str, work_dir: str | None = None, made_dirs: list[str] = ()):
    """Turns exceptions into TransientError (retried) or JobError (final, JSON-safe message)."""

    try:
        yield
    except (TransientError, JobError):
        raise
    except TweenError as e:
        _drop(work_dir, made_dirs)
        raise JobError(str(e)) from None
    except SoftTimeLimitExceeded:
        _drop(work_dir, made_dirs)
        raise soft_limit_error(shot) from None
    except OSError as e:
        if e.errno in TRANSIENT_ERRNOS or isinstance(e, ConnectionError | TimeoutError):
            raise TransientError(f"{shot}: {e}") from e
        _drop(work_dir, made_dirs)
        raise JobError(f"{shot}: {e}") from None
    except Exception as e:
        _drop(work_dir, made_dirs)
        raise JobError(f"{shot}: {type(e).__name__}: {e}") from e


def _drop(work_dir: str | None, made_dirs: list[str] = ()) -> None:
    """Removes the job's work folder, and (``made_dirs``, on failure) the output folders that
    did not exist when the job was submitted, if nothing else is in them."""
    if work_dir:
        shutil.rmtree(work_dir, ignore_errors=True)
        try:
            os.rmdir(os.path.dirname(work_dir))  # .tween-work itself, once no other job uses it
        except OSError:
            pass
    for d in made_dirs:  # deepest first
        try:
            os.rmdir(d)
        except OSError:
            break


class FarmTask(Task):
    """Retries transient errors with exponential back-off and jitter, nothing else."""

    autoretry_for = (TransientError,)
    retry_backoff = 2
    retry_jitter = True

    max_retries = app.conf.tween.max_retries
    # A retry is an ETA message held by a worker; keep it well inside the visibility timeout.
    retry_backoff_max = min(app.conf.tween.retry_backoff_max, max(1, app.conf.tween.visibility_timeout // 2))


def _opts(opts: dict):

    return FillOptions(**opts)


def _check(shot: str, opts: dict, job: dict) -> None:
    jobpaths.check_job(shot, opts, app.conf.tween.shot_roots, job.get("work_dir"))


@app.task(name="tween.validate", base=FarmTask, bind=True)
def validate(self, shot: str, opts: dict, job: dict) -> dict:
    """Refuses paths outside the shot roots, then checks the shot can be filled."""

    with _sorted_errors(shot):
        _check(shot, opts, job)
        info = fill.validate_shot(shot, _opts(opts))
    return runtime.small_json({"shot": shot, **(info or {})})


@app.task(name="tween.fill_take", base=FarmTask, bind=True)
def fill_take(self, shot: str, opts: dict, take: int, job: dict) -> str:
    """Fills one take; returns the path of its .npz under the job's work folder."""

    with _sorted_errors(shot, job["work_dir"], job.get("made_dirs", ())):
        _check(shot, opts, job)
        os.makedirs(job["work_dir"], exist_ok=True)
        return str(fill.fill_take(shot, _opts(opts), take, job["work_dir"]))


@app.task(name="tween.write_layer", base=FarmTask, bind=True)
def write_layer(self, take_files: list[str], shot: str, opts: dict, job: dict) -> dict:
    """The chord body: writes the filled layer (and review layer) from every take."""

    with _sorted_errors(shot, job["work_dir"], job.get("made_dirs", ())):
        _check(shot, opts, job)
        out = fill.write_layers(shot, _opts(opts), list(take_files), job_id=job["id"])
    return runtime.small_json(out)


@app.task(name="tween.render_review", base=FarmTask, bind=True)
def render_review(self, layer: dict, shot: str, opts: dict, job: dict) -> dict:
    """Drops the work folder, then renders the review of each take when asked to."""
    # The work folder goes here and not in write_layer: if write_layer is delivered twice,
    # its take files must still be there.
    _drop(job["work_dir"])
    result = dict(layer)
    if not job.get("render"):
        return result
    with _sorted_errors(shot):
        _check(shot, opts, job)
        try:
            from render.review import render_review as render_fn
        except ImportError:
            result["renders"] = None
            result["render_note"] = "render.review is not available on this worker; review not rendered"
            return result
        out_dir = os.path.join(os.path.dirname(layer["review"] or layer["layer"]), "review")
        n_takes = int(layer.get("takes") or 1)
        # One take has no variant set to select: render the stage as composed.
        takes = list(range(n_takes)) if n_takes > 1 else [None]
        same = {int(k): int(v) for k, v in (layer.get("same_as") or {}).items()}
        renders: list = []
        for t in takes:  # a take identical to an earlier one is not rendered again
            if t in same:
                renders.append(dict(renders[same[t]], same_as=same[t]))
            else:
                renders.append(
                    runtime.small_json(render_fn(layer["review"] or layer["layer"], out_dir, take=t))
                )
        result["renders"] = renders
    return result


_WORKER_PID = None


@worker_init.connect
def _init_worker(**_):
    # In the worker's main process: an embedded worker dies with its `tween fill` client.
    global _WORKER_PID
    parent = os.environ.get(runtime.PARENT_ENV)
    if parent:
        _WORKER_PID = os.getpid()
        runtime.watch_parent(int(parent))


@worker_process_init.connect
def _init_process(**_):
    # After fork, in each pool child: one ORT session (and GL context) per process, never in
    # the parent before fork. A pool child of an embedded worker dies with the worker.
    if _WORKER_PID is not None:
        runtime.die_with(_WORKER_PID)
    runtime.init_process()
