"""The stages of a shot's fill job. They pass file paths and small JSON, never arrays.

Each stage is a thin wrapper over :mod:`pipeline.fill` (looked up at call time, so the same
functions serve Celery, a direct in-process run and any other farm adapter). Errors are
sorted in one place: transient I/O and connection errors retry with back-off; anything else
(a bad shot above all) fails the job at once with its message stored on the task.

Every stage runs under :func:`workers.control.watch`: a heartbeat (and on Redis a renewed
message lease) while it runs, and the job's cancel record read when it starts and at every
heartbeat. A cancelled job's stage undoes the job (:func:`workers.cleanup.undo`) and fails
with "cancelled"; so does a failed review render, and the main process of a worker whose
stage hit its hard time limit (``FarmTask.on_failure``): a job that does not finish leaves
nothing behind.
"""

from __future__ import annotations

import errno
import os
import socket
import sys
import threading
import time
from contextlib import contextmanager

from celery import Task
from celery.exceptions import SoftTimeLimitExceeded
from celery.signals import task_internal_error, worker_init, worker_process_init

from pipeline.errors import TweenError
from pipeline.fill import api as fill
from pipeline.fill.api import FillOptions
from pipeline.fill.options import MAX_TAKES
from pipeline.usd.write import check_out_dir, default_out_dir
from render.scene import list_takes
from workers import cleanup, control, runtime
from workers import paths as jobpaths
from workers.app import app
from workers.errors import JobError, TransientError, end_for_full_store, exit_on_full_store, store_full
from workers.limits import render_limit_message, soft_limit_error
from workers.sqlite_transport import broker_folder

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


#: errnos of a write the folder itself refuses: a read-only mount, a folder (an ACL, a
#: root-squashed NFS export) this user may not write.
UNWRITABLE_ERRNOS = {errno.EROFS, errno.EACCES, errno.EPERM}


def _out_folder(shot: str, opts: dict) -> str:
    """The folder the job writes its layers (and its ``.tween-work`` temp) in, as the user
    named it: ``--out-dir``, else the shot's folder."""
    return os.path.abspath(opts["out_dir"]) if opts.get("out_dir") else str(default_out_dir(shot))


def _unwritable(e: OSError, shot: str, out: str | None) -> JobError | None:
    """The line for a write that the job's output folder ``out`` refused (made read-only
    after the job was submitted): it names that folder, not the job's temp inside it (the
    raw error named ``.tween-work``, which the user never made), and what to do."""
    if out is None or e.errno not in UNWRITABLE_ERRNOS or not e.filename:
        return None
    path = os.path.abspath(os.fsdecode(e.filename))
    # EROFS is only ever a write; a permission error is one where the job makes its temp (a
    # shot in that folder that cannot be read is another error, said as it is).
    where = out if e.errno == errno.EROFS else os.path.join(out, ".tween-work")
    if path != out and os.path.commonpath([path, where]) != where:
        return None
    return JobError(
        f"{shot}: output folder {out} cannot be written ({e.strerror}); make it writable, or run the "
        "job again with another --out-dir DIR"
    )


class JobCancelledError(JobError):
    """The stage's job was cancelled (``tween cancel``, or its ``tween fill`` interrupted)."""


@contextmanager
def _sorted_errors(
    shot: str,
    work_dir: str | None = None,
    made_dirs: list[str] = (),
    work: dict | None = None,
    out: str | None = None,
):
    """Turns exceptions into TransientError (retried) or JobError (final, JSON-safe message).
    With ``work`` ({"frames", "takes"}) a soft time limit is the review render's; with
    ``out`` (the output folder) a write refused there names that folder."""

    try:
        yield
    except (TransientError, JobError):
        raise
    except TweenError as e:
        _drop(work_dir, made_dirs)
        raise JobError(str(e)) from None
    except SoftTimeLimitExceeded:
        _drop(work_dir, made_dirs)
        if work is not None:
            raise JobError(render_limit_message(shot, "soft", work["frames"], work["takes"])) from None
        raise soft_limit_error(shot) from None
    except OSError as e:
        if e.errno in TRANSIENT_ERRNOS or isinstance(e, ConnectionError | TimeoutError):
            raise TransientError(f"{shot}: {e}") from e
        _drop(work_dir, made_dirs)
        raise _unwritable(e, shot, out) or JobError(f"{shot}: {e}") from None
    except Exception as e:
        _drop(work_dir, made_dirs)
        raise JobError(f"{shot}: {type(e).__name__}: {e}") from e


def _drop(work_dir: str | None, made_dirs: list[str] = ()) -> None:
    """Removes the job's work folder, and (``made_dirs``, on failure) the output folders that
    did not exist when the job was submitted, if nothing else is in them."""
    cleanup.drop_work(work_dir, made_dirs)


def _job_args(name: str, args) -> tuple[str, dict, dict] | None:
    """(shot, opts, job) from a fill stage's arguments, by task name."""
    args = list(args or ())
    try:
        if name in ("tween.validate", "tween.fill_take"):
            return args[0], args[1], args[-1]
        if name in ("tween.write_layer", "tween.render_review"):
            return args[1], args[2], args[3]
        if name == "tween.render_version":
            return args[0], {}, args[1]
    except IndexError:
        return None
    return None


class FarmTask(Task):
    """Retries transient errors with exponential back-off and jitter, nothing else."""

    autoretry_for = (TransientError,)
    # The job's own errors (a bad shot, a cancel, a time limit's line) are logged as one line.
    throws = (JobError,)
    retry_backoff = 2
    retry_jitter = True

    max_retries = app.conf.tween.max_retries
    # A retry is an ETA message held by a worker; keep it well inside the visibility timeout.
    retry_backoff_max = min(app.conf.tween.retry_backoff_max, max(1, app.conf.tween.visibility_timeout // 2))

    def on_failure(self, exc, task_id, args, kwargs, einfo):
        # Celery calls this in the worker's main process for a stage killed at its hard time
        # limit (its pool process is gone: nothing ran its cleanup); the job is undone here.
        if type(exc).__name__ != "TimeLimitExceeded":
            return
        found = _job_args(self.name, args)
        if found:
            # The killed process may write for a moment more (billiard kills it after a grace
            # period): the job is undone once it is gone, on a thread of this main process.
            beat = control.read_beat(app, task_id) or {}
            pid = beat.get("pid") if beat.get("host") == socket.gethostname() else None
            threading.Thread(target=_undo_after, args=(pid, *found), daemon=True).start()


def _undo_after(pid: int | None, shot: str, opts: dict, job: dict, wait_s: float = 30.0) -> None:
    """Undoes ``job`` once process ``pid`` (the stage's, killed) has died."""
    from pipeline.usd.files import pid_alive

    deadline = time.monotonic() + wait_s
    while pid and pid_alive(int(pid)) and time.monotonic() < deadline:
        time.sleep(0.1)
    try:
        cleanup.undo(shot, opts, job)
    except Exception as e:  # the failure itself is recorded; say why files stayed
        print(f"tween worker: {shot}: job {job.get('id')} not cleaned up: {e}", file=sys.stderr)


@contextmanager
def _stage(task, shot: str, opts: dict, job: dict, stage: str):
    """Runs a stage under the job's watch (heartbeat, lease, cancel); a cancelled job is
    undone and the stage fails with its one line."""
    try:
        with control.watch(app, job["id"], task.request.id, stage, task.request.hostname or ""):
            yield
    except control.JobCancelled:
        cleanup.undo(shot, opts, job)
        rec = control.cancel_record(app, job["id"]) or {}
        by = f" by {rec['by']}" if rec.get("by") else ""
        raise JobCancelledError(f"{shot}: job {job['id']} cancelled{by}") from None


def _opts(opts: dict):

    return FillOptions(**opts)


def _check(shot: str, opts: dict, job: dict) -> None:
    jobpaths.check_job(shot, opts, app.conf.tween.shot_roots, job.get("work_dir"))


def _checked_layer(layer, shot: str, opts: dict, job: dict) -> int:
    """The job's paths and what the layer stage handed the review stage (through the result
    backend, which anyone who can write there can forge): its layer and review paths inside
    the shot roots, as every path of a job; its takes a count a fill makes (1 to MAX_TAKES: a
    forged 10**9 made the worker allocate 11 GB). Returns the takes."""
    _check(shot, opts, job)
    if not isinstance(layer, dict):
        raise JobError(f"{shot}: the layer stage handed no layer ({type(layer).__name__})")
    for role in ("layer", "review"):
        p = layer.get(role)
        if p is not None and not isinstance(p, str):
            raise JobError(f"{shot}: the layer stage handed a {role} path that is no path ({p!r:.60})")
        if p:
            jobpaths.check_under_roots(p, app.conf.tween.shot_roots, f"{role} layer")
    n = layer.get("takes") or 1
    if type(n) is not int or not 1 <= n <= MAX_TAKES:
        raise JobError(f"{shot}: the layer stage handed {n!r:.60} takes; a fill makes 1 to {MAX_TAKES}")
    return n


@app.task(name="tween.validate", base=FarmTask, bind=True)
def validate(self, shot: str, opts: dict, job: dict) -> dict:
    """Refuses paths outside the shot roots, then checks the shot can be filled."""

    with _stage(self, shot, opts, job, "validate"), _sorted_errors(shot):
        _check(shot, opts, job)
        info = fill.validate_shot(shot, _opts(opts))
    return runtime.small_json({"shot": shot, **(info or {})})


@app.task(name="tween.fill_take", base=FarmTask, bind=True)
def fill_take(self, shot: str, opts: dict, take: int, job: dict) -> str:
    """Fills one take; returns the path of its .npz under the job's work folder."""

    with (
        _stage(self, shot, opts, job, f"take {take + 1}"),
        _sorted_errors(shot, job["work_dir"], job.get("made_dirs", ()), out=_out_folder(shot, opts)),
    ):
        _check(shot, opts, job)
        # Refused as the client refuses it, by mode bits too (a folder published since the
        # job was submitted stays untouched even by a root worker), before the temp is made.
        check_out_dir(shot, opts.get("out_dir"))
        os.makedirs(job["work_dir"], exist_ok=True)
        cleanup.note_job(job["work_dir"], shot, opts, job)
        out = str(fill.fill_take(shot, _opts(opts), take, job["work_dir"]))
    return out


@app.task(name="tween.write_layer", base=FarmTask, bind=True)
def write_layer(self, take_files: list[str], shot: str, opts: dict, job: dict) -> dict:
    """The chord body: writes the filled layer (and review layer) from every take."""

    with (
        _stage(self, shot, opts, job, "layer"),
        _sorted_errors(shot, job["work_dir"], job.get("made_dirs", ()), out=_out_folder(shot, opts)),
    ):
        _check(shot, opts, job)
        check_out_dir(shot, opts.get("out_dir"))  # before its lock file is made there
        out = fill.write_layers(shot, _opts(opts), list(take_files), job_id=job["id"])
    return runtime.small_json(out)


@app.task(name="tween.render_review", base=FarmTask, bind=True)
def render_review(self, layer: dict, shot: str, opts: dict, job: dict) -> dict:
    """Drops the work folder, then renders the review of each take when asked to. Its time
    limits are the render's, sized by the job's frames × takes (``job["limits"]``)."""
    with _stage(self, shot, opts, job, "review"):
        with _sorted_errors(shot):
            n_takes = _checked_layer(layer, shot, opts, job)
        result = dict(layer)
        if job.get("render"):
            try:
                result["renders"] = _render_takes(layer, shot, job, n_takes)
            except ImportError:
                result["renders"] = None
                result["render_note"] = "render.review is not available on this worker; review not rendered"
            except BaseException:
                # A job that fails leaves no partial media (nor the version it wrote).
                cleanup.undo(shot, opts, job)
                raise
        # The work folder goes last: if write_layer is delivered twice, its take files must
        # still be there; and an embedded job whose client was killed before this point is
        # found by it (its job.json), and undone, by the next run (jobs.clean_dead_work).
        _drop(job["work_dir"])
    return result


@app.task(name="tween.render_version", base=FarmTask, bind=True)
def render_version(self, review: str, job: dict) -> dict:
    """A render-only job: the review media of a fill version written earlier (the dailies
    page's "render"). Failed or cancelled, it removes the media it made, never the version."""
    with _stage(self, review, {}, job, "review"):
        try:
            with _sorted_errors(review):
                layer = {"review": review, "layer": review, "takes": len(list_takes(review)) or 1}
                n_takes = _checked_layer(layer, review, {}, job)
            return {"review": review, "renders": _render_takes(layer, review, job, n_takes)}
        except BaseException:
            cleanup.undo(review, {}, job)
            raise


def _render_takes(layer: dict, shot: str, job: dict, n_takes: int) -> list:
    """The review media of each of the ``n_takes`` takes of ``layer`` (checked by
    :func:`_checked_layer`)."""
    work = job.get("work") or {"frames": 1, "takes": n_takes}
    with _sorted_errors(shot, work=work):
        from render.review import render_review as render_fn

        out_dir = cleanup.review_dir(layer)
        # A run of this stage that died (its worker killed) left its scratch: the stage is
        # being run again, so that run is over.
        for p in cleanup.clean_scratch(out_dir, job["id"]):
            print(f"tween worker: removed {p}, left by an earlier run of job {job['id']}", file=sys.stderr)
        # One take has no variant set to select: render the stage as composed.
        takes = list(range(n_takes)) if n_takes > 1 else [None]
        same = {int(k): int(v) for k, v in (layer.get("same_as") or {}).items()}
        renders: list = []
        for t in takes:  # a take identical to an earlier one is not rendered again
            if t in same:
                renders.append(dict(renders[same[t]], same_as=same[t]))
            else:
                out = render_fn(layer["review"] or layer["layer"], out_dir, take=t, job=job["id"])
                renders.append(runtime.small_json(out))
    return renders


_WORKER_PID = None


@worker_init.connect
def _init_worker(**_):
    # In the worker's main process: an embedded worker dies with its `tween fill` client, and
    # ends (its client told why) once its stores are full.
    global _WORKER_PID
    parent = os.environ.get(runtime.PARENT_ENV)
    if parent:
        _WORKER_PID = os.getpid()
        runtime.watch_parent(int(parent))
        exit_on_full_store()


@task_internal_error.connect
def _internal_error(exception=None, **_):
    # Celery's own failure to record a stage (its result store full) is logged and dropped:
    # the stage's client would wait for ever. An embedded worker ends instead.
    if store_full(exception, broker_folder(app.conf.broker_url)):
        end_for_full_store()


@worker_process_init.connect
def _init_process(**_):
    # After fork, in each pool child: one ORT session (and GL context) per process, never in
    # the parent before fork. A pool child of an embedded worker dies with the worker.
    if _WORKER_PID is not None:
        runtime.die_with(_WORKER_PID)
    runtime.init_process()
