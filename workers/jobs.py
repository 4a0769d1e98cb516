"""Submitting shots as jobs, and reading their state back.

A job is one shot: ``validate → group(fill_take × N) → write_layer (chord) → render_review``.
Every stage gets a task id derived from the job id, and a small job record (shot, takes,
stage ids) is stored in the result backend under the job id, so ``tween status JOB`` works
from any host with nothing but the id.
"""

from __future__ import annotations

import os
import sys
import time
import uuid
from dataclasses import asdict, dataclass, field, replace
from datetime import UTC, datetime

from celery import chain, chord, group
from celery import states as cstates
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from pipeline.fill.options import PATH_FIELDS, FillOptions
from pipeline.library.options import command_args as library_args
from pipeline.usd.files import clean_dead_temps, dead_temp
from render.scene import list_takes
from workers import cleanup, control
from workers import paths as jobpaths
from workers.app import SUBMITTED, app, rig_app, train_app
from workers.errors import store_full
from workers.limits import failure_message, render_limits, train_limit_message
from workers.settings import EMBEDDED_QUEUE_PREFIX
from workers.sqlite_transport import broker_folder


@dataclass
class JobState:
    id: str
    shot: str = ""
    # UNKNOWN, QUEUED, RUNNING, SUCCESS, FAILURE, CANCELLING (cancelled, a stage still
    # stopping), CANCELLED
    state: str = "UNKNOWN"
    done: int = 0
    total: int = 0
    stage: str = ""
    error: str | None = None
    result: dict | None = None
    stages: dict = field(default_factory=dict)
    #: The running stage's worker when it stopped sending heartbeats: {"worker", "host",
    #: "pid", "last_beat" (epoch s), "silent_s", "requeue_by" (epoch s, or None)}.
    lost: dict | None = None
    #: Each time the running stage was requeued after its worker was lost: {"at", "from", …}.
    requeued: list = field(default_factory=list)
    cancel: dict | None = None  # the job's cancel record ({"time", "by"})
    record: dict = field(default_factory=dict)  # the job record (shot, takes, paths)

    @property
    def finished(self) -> bool:
        return self.state in ("SUCCESS", "FAILURE", "UNKNOWN", "CANCELLED")

    def as_dict(self) -> dict:
        keys = ("id", "shot", "state", "done", "total", "stage", "error", "result", "lost", "requeued")
        return {k: getattr(self, k) for k in keys}


def stage_ids(job_id: str, takes: int, kind: str = "fill") -> list[tuple[str, str]]:
    """(stage name, task id) in execution order; a render-only job (``kind="review"``) has one."""
    if kind == "review":
        return [("review", f"{job_id}.review")]
    return (
        [("validate", f"{job_id}.validate")]
        + [(f"take {t + 1}/{takes}", f"{job_id}.take{t}") for t in range(takes)]
        + [("layer", f"{job_id}.layer"), ("review", f"{job_id}.review")]
    )


def work_dir_for(shot: str, opts: dict, job_id: str, owner: str | None = None) -> str:
    """The job's folder of take files, beside its layers. With ``owner`` (``pid@host`` of an
    embedded client, whose jobs die with it) it is named so that the next run can remove it
    once that client is dead."""
    base = opts.get("out_dir") or os.path.dirname(shot)
    return os.path.join(base, ".tween-work", f".{job_id}.{owner}.tmp" if owner else job_id)


def missing_dirs(path: str | None) -> list[str]:
    """``path`` and its parents that do not exist (deepest first): a failed job removes those
    it made, if empty, so that a refused fill leaves no new output folder."""
    out: list[str] = []
    p = os.path.abspath(path) if path else None
    while p and not os.path.exists(p) and os.path.dirname(p) != p:
        out.append(p)
        p = os.path.dirname(p)
    return out


def clean_dead_work(shot: str, opts: dict) -> None:
    """Undoes the embedded jobs whose client has died (killed mid-job): their work folders,
    and what they wrote (a version's layers, review media, scratch), found by the job id in
    each work folder's ``job.json``."""

    work = os.path.join(opts.get("out_dir") or os.path.dirname(shot), ".tween-work")
    if os.path.isdir(work):
        for e in list(os.scandir(work)):
            if e.is_dir(follow_symlinks=False) and dead_temp(e.name):
                undone = cleanup.undo_dead(e.path)
                if undone:
                    rec, removed = undone
                    print(f"tween: removed job {rec['id']} of {rec['shot']}, left unfinished by a tween fill "
                          f"that was killed ({len(removed)} file(s) and folder(s))", file=sys.stderr)  # fmt: skip
        clean_dead_temps(work, quiet=True)
        try:
            os.rmdir(work)
        except OSError:
            pass


def build(shot: str, opts: dict, job: dict, queue: str):
    """The job's canvas, with deterministic task ids and an explicit queue on every stage.
    The fill stages run under the fill limits (the worker's ``task_time_limit``); the review
    render under its own, ``job["limits"]["review"]`` = (soft, hard) seconds."""
    ids = dict(stage_ids(job["id"], job["takes"]))
    o = {"queue": queue}
    soft, hard = (job.get("limits") or {}).get("review") or render_limits(1, job["takes"])
    takes = group(
        app.signature("tween.fill_take", (shot, opts, t, job), immutable=True, task_id=ids[name], **o)
        for t, name in enumerate(n for n in ids if n.startswith("take"))
    )
    layer = app.signature("tween.write_layer", (shot, opts, job), task_id=ids["layer"], **o)
    return chain(
        app.signature("tween.validate", (shot, opts, job), immutable=True, task_id=ids["validate"], **o),
        chord(takes, layer),
        app.signature(
            "tween.render_review",
            (shot, opts, job),
            task_id=ids["review"],
            soft_time_limit=soft,
            time_limit=hard,
            **o,
        ),  # fmt: skip
    )


def make_opts(**kw) -> dict:
    """FillOptions as the JSON dict that travels in messages (paths made absolute)."""

    opts = asdict(FillOptions(**{k: v for k, v in kw.items() if v is not None}))
    for key in PATH_FIELDS:
        if opts.get(key):
            opts[key] = os.path.abspath(opts[key])
    return opts


def submit(
    shots: list[str],
    opts: dict,
    *,
    render: bool = False,
    roots=None,
    queue: str | None = None,
    sending=None,
) -> list[str]:
    """Sends one job per shot; returns the job ids at once. Refuses paths outside ``roots``.
    ``sending`` is called with each job's id before anything of it is sent; once it returns
    false no more job is sent, and the ids returned are those sent."""
    roots = app.conf.tween.shot_roots if roots is None else roots
    queue = queue or app.conf.task_default_queue
    owner = None
    if queue.startswith(EMBEDDED_QUEUE_PREFIX):
        from pipeline.usd.files import owner_tag

        owner = owner_tag()
    planned = []
    for shot in shots:  # every path is checked before anything is sent: all or nothing
        shot = os.path.abspath(shot)
        job_id = uuid.uuid4().hex
        job = {"id": job_id, "takes": int(opts.get("takes") or 1), "render": bool(render)}
        job["work_dir"] = work_dir_for(shot, opts, job_id, owner)
        job["made_dirs"] = missing_dirs(opts.get("out_dir"))
        if render:  # the render's limits, sized by its work: frames × takes
            job["work"] = {"frames": _review_frames(shot), "takes": job["takes"]}
            job["limits"] = {"review": list(render_limits(job["work"]["frames"], job["takes"]))}
        if roots:  # the worker checks again against its own roots
            jobpaths.check_job(shot, opts, roots, job["work_dir"])
        planned.append((shot, job))
    if owner:
        for shot, _ in planned:
            clean_dead_work(shot, opts)
    sent = []
    try:
        for shot, job in planned:
            if sending is not None and not sending(job["id"]):
                break
            sent.append(job["id"])
            rec = {
                "shot": shot,
                "takes": job["takes"],
                "render": job["render"],
                "queue": queue,
                "time": time.time(),
                # what a client that cancels needs to undo the job (workers/cleanup.py)
                "out_dir": opts.get("out_dir") or "",
                "work_dir": job["work_dir"],
                "made_dirs": job["made_dirs"],
                "work": job.get("work"),
            }
            app.backend.store_result(job["id"], rec, SUBMITTED)
            build(shot, opts, job, queue).apply_async()
    finally:
        _drop_result_subscriptions()
    return sent


def submit_review(review: str, *, roots=None, queue: str | None = None) -> str:
    """Sends a render-only job: the review media of the fill version whose review layer is
    ``review`` (``<stem>.review.vNNN``), into ``review/`` beside it; returns its id at once.
    Its render limits are sized like a fill's render (frames × takes)."""
    roots = app.conf.tween.shot_roots if roots is None else roots
    queue = queue or app.conf.task_default_queue
    review = os.path.abspath(review)
    if roots:
        jobpaths.check_under_roots(review, roots, "review layer")
    takes = len(list_takes(review)) or 1
    job_id = uuid.uuid4().hex
    folder = cleanup.review_dir({"review": review})
    job = {
        "id": job_id,
        "kind": "review",
        "review": review,
        "takes": takes,
        "render": True,
        # what an undo keeps: the version's media that were there before this job
        "existing": sorted(p.name for p in cleanup.version_media(review, folder)),
        "work": {"frames": _review_frames(review), "takes": takes},
    }
    job["limits"] = {"review": list(render_limits(job["work"]["frames"], takes))}
    soft, hard = job["limits"]["review"]
    rec = {"shot": review, "kind": "review", "review": review, "existing": job["existing"], "takes": takes,
           "render": True, "queue": queue, "time": time.time(), "out_dir": os.path.dirname(review),
           "work": job["work"]}  # fmt: skip
    try:
        app.backend.store_result(job_id, rec, SUBMITTED)
        app.signature(
            "tween.render_version", (review, job), task_id=f"{job_id}.review", queue=queue,
            soft_time_limit=soft, time_limit=hard,
        ).apply_async()  # fmt: skip
    finally:
        _drop_result_subscriptions()
    return job_id


def _review_frames(shot: str) -> int:
    """Frames per take of the shot's review (render.review.review_frames); 1 when unknown."""
    try:
        from render.review import review_frames

        return max(1, review_frames(shot))
    except Exception:  # the worker says what is wrong with the shot; the base limit stands
        return 1


def _drop_result_subscriptions(celery_app=None) -> None:
    """Closes the Redis result pub/sub the backend opened for every sent task.

    This client polls results instead; left open, the AsyncResults finalised at interpreter
    exit try to unsubscribe on a dead connection and print tracebacks.
    """
    rc = getattr((celery_app or app).backend, "result_consumer", None)
    if rc is not None and hasattr(rc, "subscribed_to"):
        rc.subscribed_to.clear()
        rc.stop()


def _meta(task_id: str) -> dict:
    return app.backend.get_task_meta(task_id)


def state(job_id: str) -> JobState:
    """The job's state from its record and its stages' results."""
    rec = _meta(job_id)
    js = JobState(id=job_id)
    if rec.get("status") != SUBMITTED or not isinstance(rec.get("result"), dict):
        js.error = f"{job_id}: no such job (unknown id, or its record expired)"
        return js
    info = rec["result"]
    js.record = info
    js.shot, stages = info["shot"], stage_ids(job_id, int(info["takes"]), info.get("kind") or "fill")
    js.total, js.state = len(stages), "QUEUED"
    js.cancel = control.record(_meta(control.cancel_id(job_id)), control.CANCEL_STATE)
    failures = []
    # Stages are read one by one while the worker writes them: a failure is written to the
    # failing stage, then to every later one, so a later stage can read FAILURE while an
    # earlier one still read STARTED. The stages before the first failed one are read again.
    metas = {tid: _meta(tid) for _, tid in stages}
    first_failed = next(
        (i for i, (_, tid) in enumerate(stages) if metas[tid].get("status") == cstates.FAILURE), None
    )
    if first_failed:
        metas.update({tid: _meta(tid) for _, tid in stages[:first_failed]})
    for name, tid in stages:
        m = metas[tid]
        st = m.get("status", cstates.PENDING)
        js.stages[name] = st
        if st == cstates.SUCCESS:
            js.done += 1
        elif st in (cstates.STARTED, cstates.RETRY):
            js.state, js.stage = "RUNNING", name
        elif st == cstates.FAILURE:
            failures.append((name, app.backend.exception_to_python(m.get("result")), tid))
    if js.done and js.state == "QUEUED" and js.done < js.total:
        js.state = "RUNNING"
    running = [(n, tid) for n, tid in stages if js.stages[n] in (cstates.STARTED, cstates.RETRY)]
    if running:
        _heartbeats(js, running)
    if js.done == js.total and not failures:
        js.state, js.stage = "SUCCESS", ""
        js.result = _meta(stages[-1][1]).get("result")
    elif js.cancel is not None:
        # Cancelled: done once no stage runs any more (a running one stops at its next
        # heartbeat; one whose worker is lost will never report).
        live = [n for n, _ in running if js.lost is None]
        js.state = "CANCELLING" if live else "CANCELLED"
        js.stage = live[0] if live else ""
        js.error = f"{js.shot}: job {job_id} cancelled" + (
            f" by {js.cancel['by']}" if js.cancel.get("by") else ""
        )
    elif failures:
        # A failed take also fails the chord body with a ChordError; report the cause.
        name, exc, tid = ([f for f in failures if type(f[1]).__name__ != "ChordError"] or failures)[0]
        js.state, js.stage = "FAILURE", name
        silent = _silent_before(tid, metas[tid]) if type(exc).__name__ == "TimeLimitExceeded" else None
        js.error = failure_message(exc, js.shot, stage=name, work=info.get("work"), silent_s=silent)
    return js


def _silent_before(task_id: str, meta: dict) -> float | None:
    """Seconds between a failed stage's last heartbeat and its failure, when its beats had
    stopped well before (more than :func:`control.dead_after`), else None: a stage killed at
    its hard time limit while its beats went on simply ran out of time."""
    beat = control.record(_meta(control.beat_id(task_id)), control.BEAT_STATE)
    done = meta.get("date_done")
    if not beat or beat.get("ended") or not isinstance(beat.get("time"), (int, float)) or not done:
        return None
    try:
        when = done if isinstance(done, datetime) else datetime.fromisoformat(str(done))
    except ValueError:
        return None
    if when.tzinfo is None:  # the database backend stores UTC without a zone
        when = when.replace(tzinfo=UTC)
    gap = when.timestamp() - float(beat["time"])
    return gap if gap > control.dead_after(app.conf.tween, beat) else None


def _heartbeats(js: JobState, running: list[tuple[str, str]]) -> None:
    """Reads the running stages' heartbeats: a stage whose worker stopped sending them is
    ``lost`` (with when the broker requeues it); one requeued before says so."""
    s = app.conf.tween
    now = time.time()
    for name, tid in running:
        beat = control.record(_meta(control.beat_id(tid)), control.BEAT_STATE)
        if not beat:
            continue  # started a moment ago: no beat yet
        js.requeued = list(beat.get("requeued") or [])
        silent = now - float(beat.get("time") or now)
        if not beat.get("ended") and silent > control.dead_after(s, beat):
            # Redis restores the message visibility_timeout after its last renewal, at the
            # next restore sweep; other brokers redeliver when the connection drops.
            by = float(beat["time"]) + s.visibility_timeout + s.restore_interval if s.is_redis else None
            js.lost = {"stage": name, "worker": beat.get("worker"), "host": beat.get("host"),
                       "pid": beat.get("pid"), "last_beat": beat.get("time"), "silent_s": round(silent, 1),
                       "requeue_by": by}  # fmt: skip
            js.stage = name
            return


def cancel(job_ids: list[str], why: str = "") -> dict[str, JobState]:
    """Writes each unfinished job's cancel record; returns each job's state before it. A job
    that finished (or is unknown) is left as it is."""
    out = {}
    for j in job_ids:
        js = state(j)
        if not js.finished:
            control.request_cancel(app, j, why)
        out[j] = js
    return out


def cancel_sent(job_ids: list[str], why: str = "") -> None:
    """Writes each job's cancel record, whatever its state (:func:`cancel` leaves a job it
    does not find): for the jobs a client was interrupted while sending, the last of which
    may be half sent, its record or its message still on the way, so that none of them runs
    whatever of it reaches the farm (its first stage reads the cancel record)."""
    for j in job_ids:
        control.request_cancel(app, j, why)


def undo_cancelled(js: JobState) -> list[str]:
    """The client's share of a cancel: once none of its stages runs, removes what the job
    wrote (idempotent; a stage that runs later undoes it too)."""
    rec = js.record
    if js.state != "CANCELLED" or not rec:
        return []
    job = {"id": js.id, "work_dir": rec.get("work_dir"), "made_dirs": rec.get("made_dirs") or (),
           "kind": rec.get("kind") or "fill", "review": rec.get("review"), "existing": rec.get("existing")}  # fmt: skip
    return cleanup.undo(js.shot, {"out_dir": rec.get("out_dir") or None}, job)


def undo_orphaned(job_ids: list[str], why: str) -> int:
    """Cancels the unfinished jobs among ``job_ids`` and removes what they wrote, now: for a
    farm that will never run them again (an embedded worker that died, its queue gone), so
    no stage can still be running. Returns how many were undone."""
    n = 0
    for j in job_ids:
        js = state(j)
        if js.finished or not js.record:
            continue
        try:
            control.request_cancel(app, j, why)
        except Exception as e:  # a full store keeps no cancel record; the files go all the same
            if not store_full(e, broker_folder(app.conf.broker_url)):
                raise
        undo_cancelled(replace(js, state="CANCELLED"))
        n += 1
    return n


def unserved_queues(queues, celery_app=None, timeout: float = 1.0) -> list[str]:
    """Those of ``queues`` no worker answering within ``timeout`` s consumes (Celery's
    remote control: each worker names the queues it takes); all of them when none answers."""
    replies = (celery_app or app).control.inspect(timeout=timeout).active_queues() or {}
    served = {q.get("name") for qs in replies.values() for q in qs or ()}
    return sorted({q for q in queues if q not in served})


def wait(
    job_ids: list[str], *, progress: bool = True, poll: float = 0.2, alive=None, timeout=None
) -> list[JobState]:
    """Polls until every job has finished; one progress bar per shot on stderr.

    ``alive`` is called each poll and may raise (the embedded launcher uses it to stop
    waiting when its worker died).
    """

    t0 = time.monotonic()
    states = {j: state(j) for j in job_ids}
    cols = (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[stage]}"),
    )
    with Progress(*cols, TimeElapsedColumn(), console=Console(stderr=True), disable=not progress) as bar:
        bars = {
            j: bar.add_task(os.path.basename(s.shot) or j, total=s.total or 1, stage=s.state.lower())
            for j, s in states.items()
        }
        while True:
            for j in job_ids:
                if not states[j].finished:
                    states[j] = state(j)
                s = states[j]
                label = (s.stage or s.state).lower() + (": worker lost" if s.lost else "")
                bar.update(bars[j], completed=s.done, stage=label)
            if all(s.finished for s in states.values()):
                return [states[j] for j in job_ids]
            if alive is not None:
                alive()
            if timeout is not None and time.monotonic() - t0 > timeout:
                raise TimeoutError(f"jobs not finished after {timeout} s")
            time.sleep(poll)


# --- per-rig model training (workers/rig_tasks.py) ---------------------------------------


def submit_train_rig(
    source: str, out: str, options: dict | None = None, roots=None, queue: str | None = None
) -> str:
    """Sends one ``tween train-rig`` job to the rig training queue; returns its id at once.

    A job record (state SUBMITTED) is stored under the id first, so ``tween status`` tells a
    queued training from an unknown id; the task's own states replace it.
    """
    from workers.rig_tasks import check_paths, train_args

    options = {k: v for k, v in (options or {}).items() if v is not None}
    source, out = os.path.abspath(source), os.path.abspath(out)
    train_args(source, out, options)  # unknown options are refused here, not on the worker
    roots = rig_app.conf.tween.shot_roots if roots is None else roots
    if roots:
        check_paths(source, out, roots)
    job_id = f"rig-{uuid.uuid4().hex}"
    queue = queue or rig_app.conf.tween.train_rig_queue
    rig_app.backend.store_result(job_id, {"kind": "train-rig", "source": source, "out": out, "queue": queue,
                                          "time": time.time()}, SUBMITTED)  # fmt: skip
    rig_app.send_task("tween.train_rig", (source, out, options), task_id=job_id, queue=queue)
    _drop_result_subscriptions(rig_app)
    return job_id


def _long_job_state(celery_app, job_id: str, stage: str, what: str) -> JobState:
    """The state of a one-task job on ``celery_app`` (a rig training, a library build): its
    SUBMITTED record, then the task's own states; ``shot`` is its source (on success the
    result's ``source``, or the ``library`` a build made)."""
    m = celery_app.backend.get_task_meta(job_id)
    st, res = m.get("status", cstates.PENDING), m.get("result")
    js = JobState(id=job_id, total=1)
    if st == SUBMITTED and isinstance(res, dict):
        js.shot, js.state, js.stage = res.get("source", ""), "QUEUED", stage
    elif st in (cstates.STARTED, "PROGRESS", cstates.RETRY):
        js.state, js.stage = "RUNNING", stage
        js.result = res if isinstance(res, dict) else None
        js.shot = (js.result or {}).get("source", "")
    elif st == cstates.SUCCESS:
        js.state, js.done, js.result = "SUCCESS", 1, res
        js.shot = (res or {}).get("source") or (res or {}).get("library", "")
    elif st == cstates.FAILURE:
        exc = celery_app.backend.exception_to_python(res)
        js.state, js.stage, js.error = "FAILURE", stage, str(exc) or type(exc).__name__
        if type(exc).__name__ in ("TimeLimitExceeded", "SoftTimeLimitExceeded"):  # named, with the way up
            setting = "train_rig_time_limit" if celery_app is rig_app else "train_time_limit"
            js.error = train_limit_message(f"{stage} {job_id}", setting, celery_app.conf.tween)
    else:
        js.error = f"{job_id}: no such {what} (unknown id, or its record expired)"
    if not js.shot and js.state != "UNKNOWN":  # a failure's result is its exception: the task's
        js.shot = _first_arg(m)  # own arguments (kept with it: result_extended) name the source
    return js


def _first_arg(meta: dict) -> str:
    """The first argument of the task a result ``meta`` belongs to (a rig training's clip, a
    library build's folder of takes), or ""."""
    args = meta.get("args")
    return str(args[0]) if isinstance(args, list | tuple) and args and args[0] else ""


def train_rig_state(job_id: str) -> JobState:
    """QUEUED, RUNNING (with progress in ``result``), SUCCESS, FAILURE or UNKNOWN."""
    return _long_job_state(rig_app, job_id, "train-rig", "training job")


def wait_train_rig(job_id: str, *, progress: bool = True, poll: float = 1.0, timeout=None) -> JobState:
    """Polls one training job until it finishes; a progress bar (overall fraction) on stderr."""
    t0 = time.monotonic()
    cols = (
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.fields[stage]}"),
        TimeElapsedColumn(),
    )
    with Progress(*cols, console=Console(stderr=True), disable=not progress) as bar:
        task = bar.add_task(job_id, total=1.0, stage="queued")
        while True:
            s = train_rig_state(job_id)
            p = (s.result or {}) if s.state == "RUNNING" else {}
            stage = (
                f"levels {p['levels']} it {p['iteration']}/{p['iterations']}"
                if p.get("levels")
                else s.state.lower()
            )
            bar.update(task, completed=p.get("fraction", 1.0 if s.finished else 0.0), stage=stage)
            if s.finished:
                return s
            if timeout is not None and time.monotonic() - t0 > timeout:
                raise TimeoutError(f"training {job_id} not finished after {timeout} s")
            time.sleep(poll)


def submit_library(
    folder: str, out: str, options: dict | None = None, roots=None, queue: str | None = None
) -> str:
    """Sends one ``tween library build`` job to the training queue (``tween worker --train``);
    returns its id (``lib-…``) at once. Both paths are checked against the shot roots here and
    again on the worker."""
    options = {k: v for k, v in (options or {}).items() if v not in (None, False)}
    library_args(options)  # unknown options are refused here, not on the worker
    folder, out = os.path.abspath(folder), os.path.abspath(out)
    roots = train_app.conf.tween.shot_roots if roots is None else roots
    if roots:
        jobpaths.check_under_roots(folder, roots, "takes folder")
        jobpaths.check_under_roots(out, roots, "library")
        jobpaths.check_takes_under_roots(folder, roots)
    job_id = f"lib-{uuid.uuid4().hex}"
    queue = queue or train_app.conf.tween.train_queue
    train_app.backend.store_result(job_id, {"kind": "library", "source": folder, "out": out, "queue": queue,
                                            "time": time.time()}, SUBMITTED)  # fmt: skip
    train_app.send_task("tween.library_build", (folder, out, options), task_id=job_id, queue=queue)
    _drop_result_subscriptions(train_app)
    return job_id


def library_state(job_id: str) -> JobState:
    """QUEUED, RUNNING (take D/T in ``stage``), SUCCESS (the build's summary in ``result``),
    FAILURE or UNKNOWN."""
    js = _long_job_state(train_app, job_id, "library build", "library job")
    if js.state == "RUNNING" and (js.result or {}).get("total"):
        js.stage = f"library build, take {js.result['done']}/{js.result['total']}"
    return js


def wait_library(job_id: str, *, poll: float = 1.0, timeout=None) -> JobState:
    """Polls one library job until it finishes."""
    t0 = time.monotonic()
    while True:
        s = library_state(job_id)
        if s.finished:
            return s
        if timeout is not None and time.monotonic() - t0 > timeout:
            raise TimeoutError(f"library job {job_id} not finished after {timeout} s")
        time.sleep(poll)
