"""Farm commands of the ``tween`` CLI: fill, submit, submit-train-rig, status, cancel, worker,
bench-farm."""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import sys
import threading
import time
from dataclasses import asdict
from pathlib import Path

import typer

from pipeline.errors import TweenError
from pipeline.fill.api import precheck, trust_line
from pipeline.fill.options import NOT_NETWORKS, PATH_FIELDS, FillOptions, with_fill_options
from pipeline.inputs import not_a_file
from pipeline.library.options import LibraryBuildOptions, with_library_options
from pipeline.library.store import setting_library
from pipeline.outputs import given_path, refuse_read_only
from pipeline.rig.options import TrainRigOptions, with_train_rig_options
from pipeline.staging import refuse_model
from workers import paths as jobpaths
from workers.errors import StoreFullError, store_full
from workers.runtime import thread_env
from workers.settings import cache_dir, load_settings, redact_url


def _jobs():
    """workers.jobs, the farm's client: it imports Celery, so only the commands that reach
    the farm import it (``tween fill-local`` and ``--help`` stay fast)."""
    import workers.jobs

    return workers.jobs


def _opts(opts) -> dict:
    """The job's options, checked (one line naming the option) before anything is sent, as
    the farm payload."""

    from workers.jobs import make_opts

    out = make_opts(**asdict(opts.check()))
    default = load_settings().library  # the studio's library, for every job that names none
    # (a job asking for a curve, --model spline or interp, gets the curve: no network to probe)
    if not out.get("library") and default and out.get("model") not in NOT_NETWORKS:
        # opened here: one that is no library is one line naming the setting
        out["library"] = setting_library(
            default, f"library {default} (the farm's setting: TWEEN_LIBRARY or the farm config's `library`)"
        )
    return out


def _int_opt(opt: str, value: int | None, lo: int, hi: int) -> None:
    """A whole-number option within lo..hi, or one line naming it."""

    if value is not None and not lo <= value <= hi:
        raise TweenError(f"{opt} {value}: must be from {lo} to {hi}")


def raise_settings_error() -> None:
    """The farm configuration's error, if it has one (before telling a farm command that no
    broker is configured: the broker setting may be the one that is wrong)."""
    from workers.app import SETTINGS_ERROR

    if SETTINGS_ERROR is not None:
        raise SETTINGS_ERROR


def _err(msg: str) -> None:
    print(f"tween: error: {msg}", file=sys.stderr)


def _decision(layer) -> str:
    """``, approved take N by WHO at WHEN ("note") in LAYER`` for a result layer with a
    dailies decision (:func:`pipeline.usd.dailies.decision`), else ""; never fails."""
    if not layer:
        return ""
    try:
        from pipeline.usd.dailies import decision

        d = decision(layer)
    except Exception:
        return ""
    if not d:
        return ""
    note = " ".join(str(d.get("note") or "").split())
    return (f", {d['status']} take {d['take']} by {d.get('by') or 'unknown'} at {d.get('at')}"
            + (f' ("{note}")' if note else "") + f" in {d['layer']}")  # fmt: skip


#: Exit status of a fill that was cancelled (128 + SIGINT, what a shell gives Ctrl-C).
EXIT_CANCELLED = 130
#: How long an interrupted fill, or `tween cancel`, waits for running stages to stop.
CANCEL_WAIT_S = 60.0


class _Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM while ``tween fill`` waits for its jobs."""


class _Interrupts:
    """SIGINT and SIGTERM handlers for ``tween fill``. While ``armed`` (the embedded worker
    starting, before anything is sent) the handler raises :class:`_Interrupted`. Otherwise it
    only counts: while the jobs are sent from a thread (:func:`_until_signal` ends the wait on
    a new count; a job half sent is never left running: :func:`_cancel_sent`), while
    the fill waits (:meth:`check`, called each poll, raises it there), and while the cancel
    settles (a second one stops the waiting).

    Why not raise where the signal lands while waiting: that is inside the farm client's
    library code. Inside a garbage collector's callback the exception is printed and dropped
    (the fill ran on to exit 0); inside a read of the SQLite result store the half-read
    statement keeps its lock while the exception lives, so every write to that store (the
    cancel record, the worker's results) waits out its busy timeout and retries (the fill hung
    past 90 s after "cancelling")."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self.count, self.armed, self.old = 0, True, {}

    def __enter__(self) -> _Interrupts:
        for sig in self.SIGNALS:
            self.old[sig] = signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc) -> None:
        for sig, h in self.old.items():
            signal.signal(sig, h)

    def _handler(self, signum, frame):
        self.count += 1
        if self.armed:
            self.armed = False
            raise _Interrupted()

    def check(self) -> None:
        """Raises the interrupt if a signal came (since the jobs were sent, or before)."""
        if self.count:
            raise _Interrupted()


def _exit(code: int) -> None:
    """Ends a fill or submit with ``code``. A cancelled one (130) has said how each job ended,
    so it leaves as SystemExit: the command handler adds "tween: interrupted" to a status 130
    it is given, which would be a line too many (and untrue for a job cancelled elsewhere)."""
    if code == EXIT_CANCELLED:
        sys.exit(code)
    raise typer.Exit(code)


def _shot_files(shots: list[Path]) -> list[str]:
    """The shots as given, each an existing file and each once (a shot named twice, by any
    path, made two versions of it in one run); or one line naming the first that is not."""
    seen: dict[str, str] = {}
    for p in map(str, shots):
        if why := not_a_file(p, "shot file"):
            raise TweenError(f"{p}: {why}")
        real = os.path.realpath(p)
        if real in seen:
            raise TweenError(f"{p}: the same shot as {seen[real]} (give each shot once)")
        seen[real] = p
    return list(seen.values())


def _job_ids(job_ids: list[str]) -> list[str]:
    """The job ids given, each once (``cancel J J`` said "already cancelled" of the cancel it
    had just made), or one line naming one that cannot be an id (empty: an internal error on
    Redis; a newline: a second line)."""
    for j in job_ids:
        if not j or not j.isprintable() or j != j.strip():
            raise TweenError(f"job id {j!r}: not a job id (from `tween submit` or `tween fill`)")
    return list(dict.fromkeys(job_ids))


def _clock(t) -> str:
    return time.strftime("%H:%M:%S", time.localtime(float(t))) if t else "?"


def _settle(ids: list[str], intr: _Interrupts | None = None, alive=None, timeout: float = CANCEL_WAIT_S):
    """Polls cancelled jobs until none of their stages runs (or ``timeout``, or a second
    interrupt); then removes what each cancelled job wrote. Returns the last states."""
    jobs = _jobs()

    t0 = time.monotonic()
    seen = intr.count if intr else 0
    while True:
        states = [jobs.state(j) for j in ids]
        if all(s.finished for s in states) or time.monotonic() - t0 > timeout:
            break
        if intr is not None and intr.count > seen:
            break
        if alive is not None:
            try:
                alive()
            except TweenError:
                break
        time.sleep(0.2)
    for s in states:
        jobs.undo_cancelled(s)
    return states


def _cancelled_line(s) -> str:
    by = (s.cancel or {}).get("by")
    return f"tween: {s.shot}: job {s.id} cancelled" + (f" by {by}" if by else "") + ", nothing of it kept"


def _from_interrupt(e: BaseException | None) -> bool:
    """Whether ``e`` is the interrupt, or an error raised while a library cleaned up after it
    (its context is the interrupt): while the embedded worker starts the handler raises where
    the signal lands, and code cleaning up there may fail in its turn."""
    while e is not None:
        if isinstance(e, _Interrupted):
            return True
        e = e.__context__
    return False


#: Seconds `tween fill` waits on jobs no worker has started before it asks the farm, once,
#: whether any worker consumes their queue.
IDLE_CHECK_S = 5.0


class _NoWorkerNotice:
    """Polled while `tween fill` waits on a farm: once every job has sat queued for
    IDLE_CHECK_S, asks the workers which queues they take and, where none takes the jobs'
    queue, says so once on stderr. The jobs stay queued (a worker may yet start) and the wait
    goes on: Ctrl-C cancels them as ever."""

    def __init__(self, ids: list[str]):
        self.ids, self.t0, self.asked = ids, time.monotonic(), False

    def __call__(self) -> None:
        if self.asked or time.monotonic() - self.t0 < IDLE_CHECK_S:
            return
        self.asked = True
        jobs = _jobs()
        states = [jobs.state(j) for j in self.ids]
        if not states or any(s.state != "QUEUED" or s.done for s in states):
            return
        queues = {s.record.get("queue") for s in states} - {None}
        try:
            idle = jobs.unserved_queues(queues)
        except Exception:  # the broker's own errors come through the wait itself
            return
        for q in idle:
            print(f"tween: no worker takes the farm's queue {q!r} (start one: `tween worker`); "
                  f"the job(s) wait there, Ctrl-C cancels them", file=sys.stderr)  # fmt: skip


def _run_jobs(ids: list[str], intr: _Interrupts, progress: bool, alive=None, idle=None) -> int:
    """Waits for the jobs and reports them; on SIGINT/SIGTERM cancels them, waits until they
    have stopped and undone their work, and returns 130. ``alive`` is polled while waiting
    and cancelling, ``idle`` (a _NoWorkerNotice) while waiting only."""
    jobs = _jobs()

    def poll() -> None:
        intr.check()
        if alive is not None:
            alive()
        if idle is not None:
            idle()

    intr.armed = False  # from here the polls raise it, between the farm client's reads
    try:
        intr.check()  # interrupted while the jobs were being sent
        states = jobs.wait(ids, progress=progress, alive=poll)
        intr.check()  # it came during the last poll
    except BaseException as e:
        if not _from_interrupt(e):
            raise
        states = None  # cancelled below, once the interrupt (and what its frames hold) is let go
    if states is None:
        return _cancel(jobs, ids, intr, alive)
    code = _report([s for s in states if s.state != "CANCELLED"])
    for s in states:
        if s.state == "CANCELLED":  # cancelled elsewhere (`tween cancel`)
            jobs.undo_cancelled(s)
            print(_cancelled_line(s), file=sys.stderr)
            code = EXIT_CANCELLED
    return code


#: Said by a fill interrupted once every job had ended on its own: its exit status is the
#: jobs' own.
NOTHING_CANCELLED = (
    "tween: interrupted, but every job had ended before the cancel reached it: nothing cancelled"
)


def _cancel(jobs, ids: list[str], intr: _Interrupts, alive) -> int:
    """Cancels the interrupted fill's jobs, waits until they have stopped and undone their
    work, says how each ended and returns 130. Where the interrupt cancelled nothing (it came
    in the wait's last poll, or each job ended before the cancel reached it) each job is
    reported as it ended, kept, and the status is theirs: a fill that kept its version and
    exited 130 had a script that retries on failure make a second one."""
    before = jobs.cancel(ids, why="tween fill interrupted")  # a finished job is left as it is
    live = [j for j in ids if not before[j].finished]
    if live:
        print(f"tween: interrupted: cancelling {len(live)} job(s) ({', '.join(live)})", file=sys.stderr)
    states = _settle(ids, intr, alive)
    if all(s.finished and s.state != "CANCELLED" for s in states):
        code = _report(states)
        print(NOTHING_CANCELLED, file=sys.stderr)
        return code
    for s in states:
        if s.state == "CANCELLED":
            print(_cancelled_line(s), file=sys.stderr)
        elif s.finished:  # it ended before the cancel reached it
            _report([s])
        else:
            print(f"tween: {s.shot}: job {s.id} is still stopping (`tween status {s.id}`)", file=sys.stderr)
    return EXIT_CANCELLED


def _said(paths: list[str], ids: list[str], progress: bool) -> None:
    """With progress on, each job id as it is sent, so that `tween status` can follow a fill
    that is waited for (the Blender extension polls it); --no-progress keeps stderr as it was."""
    if not progress:
        return
    for p, j in zip(paths, ids, strict=True):
        print(f"tween: job {j} submitted ({p})", file=sys.stderr, flush=True)


def _status_line(s) -> str:
    """The line of a fill job in ``tween status`` while it is not finished, or cancelled."""
    if s.state == "CANCELLED":
        by = (s.cancel or {}).get("by") or "someone"
        return f"{s.id} {s.shot}: cancelled by {by} at {_clock((s.cancel or {}).get('time'))}"
    if s.state == "CANCELLING":
        return f"{s.id} {s.shot}: cancelling ({s.stage} still stopping)"
    line = (
        f"{s.id} {s.shot}: {' '.join(filter(None, (s.state.lower(), s.stage)))} ({s.done}/{s.total} stages)"
    )
    if s.lost:
        lost = s.lost
        line = (f"{s.id} {s.shot}: worker lost: {lost['worker']} (host {lost['host']}, pid {lost['pid']}) sent "
                f"no heartbeat for {lost['silent_s']:.0f} s, since {_clock(lost['last_beat'])}, in stage "
                f"{lost['stage']} ({s.done}/{s.total} stages done); ")  # fmt: skip
        if lost.get("requeue_by"):
            line += f"the broker requeues it by {_clock(lost['requeue_by'])}"
        else:
            line += "the broker requeues it when it sees the worker's connection drop"
    if s.requeued:
        r = s.requeued[-1]
        line += f"; requeued at {_clock(r.get('at'))} after worker {r.get('from')} was lost"
    return line


def _report(states) -> int:
    """Results to stdout (per shot: layer, review, each take's MP4 and contact sheet, the
    timeline), the job id and each character's trust decision to stderr, failures to stderr;
    returns the exit code."""
    failed = 0
    for s in states:
        if s.state == "SUCCESS":
            r = s.result or {}
            line = f"{s.shot}: layer {r.get('layer')}"
            if r.get("review"):
                line += f", review {r['review']}"
            renders = r.get("renders") or []
            for i, rend in enumerate(renders):
                if isinstance(rend, dict) and rend.get("same_as") is not None:
                    line += f", take {i} = take {rend['same_as']}"
                    continue
                mp4 = rend.get("mp4") if isinstance(rend, dict) else rend
                line += f", take {i} render {mp4}"
                if isinstance(rend, dict) and rend.get("contact_sheet"):
                    line += f", take {i} contact sheet {rend['contact_sheet']}"
            timelines = {
                rend.get("timeline") for rend in renders if isinstance(rend, dict) and rend.get("timeline")
            }
            for t in sorted(timelines):
                line += f", timeline {t}"
            if r.get("render_note"):
                line += f" ({r['render_note']})"
            models = r.get("models") or {}
            if len(models) > 1:
                line += ", models " + "; ".join(f"{a}: {m}" for a, m in models.items())
            elif r.get("model"):
                line += f", model {r['model']}"
            typer.echo(line)
            print(f"tween: {s.shot}: job {s.id}", file=sys.stderr)
            same = r.get("same_as") or {}
            if same:
                pairs = ", ".join(
                    f"take {k} = take {v}" for k, v in sorted(same.items(), key=lambda kv: int(kv[0]))
                )
                print(f"tween: {s.shot}: {pairs}, bit for bit (a fill without a seed, such as the spline's): "
                      "rendered once", file=sys.stderr)  # fmt: skip
            for anim, d in (r.get("trust") or {}).items():
                if d:
                    print(f"tween: {s.shot} {anim}: {trust_line(d)}", file=sys.stderr)
        else:
            failed += 1
            _err(s.error or f"{s.shot}: job {s.id} {s.state.lower()}")
    return 2 if failed else 0


def _fill_embedded(paths: list[str], opts: dict, render: bool, concurrency: int, progress: bool) -> int:
    """``tween fill`` on its own embedded farm (:func:`_run_embedded`); its SQLite broker or
    result store on a full disk is one line naming the cache folder (SQLAlchemy's errors
    and Celery's BackendStoreError were internal errors, or kombu's AttributeError)."""
    try:
        return _run_embedded(paths, opts, render, concurrency, progress)
    except Exception as e:
        if store_full(e, cache_dir() / "farm"):
            raise StoreFullError(cache_dir() / "farm") from None
        raise


def _run_embedded(paths: list[str], opts: dict, render: bool, concurrency: int, progress: bool) -> int:
    """Starts the embedded worker, sends the jobs and waits; returns the exit code. A worker
    that dies has its unfinished jobs undone."""
    from workers.embedded import EmbeddedWorker, WorkerDied, WorkerStoreFull

    jobs = _jobs()
    # The shots' folders, as given and where their links lead (checked with symlinks followed).
    roots = [os.path.dirname(f(p)) for p in paths for f in (os.path.abspath, os.path.realpath)]
    for key, role in PATH_FIELDS.items():  # every path option's folder is a root of this farm
        if opts.get(key):
            roots.append(opts[key] if role == "dir" else os.path.dirname(opts[key]))
    # Interrupted while the worker starts: it is stopped, nothing was sent. Interrupted once
    # the jobs are reported, while it stops: it is killed at once (its warm stop took seconds,
    # the signal ignored), the jobs are kept, and the status is theirs.
    ids: list[str] = []
    seen = 0
    with _Interrupts() as intr:
        try:
            with EmbeddedWorker(roots, concurrency=concurrency, hurry=lambda: intr.count > 0) as w:
                intr.armed = False
                ids = jobs.submit(paths, opts, render=render, roots=w.roots, queue=w.queue)
                _said(paths, ids, progress)
                code = _run_jobs(ids, intr, progress, alive=w.alive)
                w.cold, seen = True, intr.count  # every job has ended: the worker is idle
        except WorkerStoreFull:  # its stores are full: its jobs' files go, unrecorded
            jobs.undo_orphaned(ids, why="its embedded worker's stores are full")
            raise StoreFullError(cache_dir() / "farm") from None
        except WorkerDied as e:  # stopped now (the with block): nothing of its jobs runs
            undone = jobs.undo_orphaned(ids, why="its embedded worker died")
            raise TweenError(f"{e}; {undone} unfinished job(s) cancelled, nothing of them kept") from None
        except BaseException as e:  # the interrupt, or a library's error raised while it landed
            if not _from_interrupt(e):
                raise
            print("tween: interrupted", file=sys.stderr)  # before anything was sent
            code = EXIT_CANCELLED
    if intr.count > seen and code != EXIT_CANCELLED:
        print("tween: interrupted while the embedded worker stopped, after the fill had finished: "
              "nothing cancelled", file=sys.stderr)  # fmt: skip
    return code


@with_fill_options
def fill(
    shots: list[Path] = typer.Argument(..., help="USD shot files (.usda/.usdc/.usd)."),
    render: bool = typer.Option(False, "--render", help="Also render the review of each take."),
    concurrency: int = typer.Option(2, "-c", "--concurrency", help="Embedded worker processes."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Progress bars on stderr."),
    opts: FillOptions = None,
):
    """Fill shots through the farm and wait; prints where the layers (and renders) are.

    With no broker configured (TWEEN_BROKER_URL or the farm config file) this runs an
    embedded farm: a local worker on a SQLite broker, started and stopped here.
    """
    jobs = _jobs()

    # The options first: a bad one is refused before Celery is even imported.
    takes = opts.takes
    opts = _opts(opts)
    _int_opt("--concurrency", concurrency, 1, 256)
    from workers.app import app as celery_app
    from workers.app import check_farm, farm_errors

    s = celery_app.conf.tween
    paths = _shot_files(shots)
    for p in paths:  # checked and said here, in seconds, by the client: the workers' stderr is their log
        precheck(p, FillOptions(**opts))
    if not s.embedded:
        for p in paths if s.shot_roots else ():  # before the broker is contacted: named as such
            jobpaths.check_job(os.path.abspath(p), opts, s.shot_roots)
        check_farm(celery_app)
        # Ctrl-C (SIGINT) or SIGTERM cancels the jobs on the farm: _run_jobs; while they are
        # sent it ends the sending at once and cancels every job begun, as `tween submit` does.
        ids: list[str] = []  # named by a connection lost while waiting: they may still run
        sending = _Sending()
        with farm_errors(celery_app, ids), _Interrupts() as intr:
            intr.armed = False  # counted, not raised, while the jobs are sent
            sent = _until_signal(intr, lambda: jobs.submit(paths, opts, render=render, sending=sending.begin))
            if sent is _SIGNALLED:
                _cancel_sent(celery_app, sending.stop(), intr, "tween fill")
            ids += sent
            _said(paths, ids, progress)
            code = _run_jobs(ids, intr, progress, idle=_NoWorkerNotice(ids))
        _exit(code)
    check_farm(celery_app)  # the embedded farm's stores
    _exit(_fill_embedded(paths, opts, render, min(concurrency, max(1, takes * len(paths))), progress))


@with_fill_options
def submit(
    shots: list[Path] = typer.Argument(..., help="USD shot files, on storage every worker sees."),
    render: bool = typer.Option(False, "--render", help="Also render the review of each take."),
    opts: FillOptions = None,
):
    """Submit shots to the farm; prints one job id per shot (stdout) and returns at once."""
    jobs = _jobs()

    opts = _opts(opts)
    from workers.app import app as celery_app
    from workers.app import check_farm, farm_errors

    raise_settings_error()
    if celery_app.conf.tween.embedded:
        _err("no broker configured (set TWEEN_BROKER_URL); `tween fill` runs an embedded farm")
        raise typer.Exit(2)
    paths = _shot_files(shots)
    for p in paths:
        precheck(p, FillOptions(**opts))
        if celery_app.conf.tween.shot_roots:  # before the broker is contacted
            jobpaths.check_job(os.path.abspath(p), opts, celery_app.conf.tween.shot_roots)
    check_farm(celery_app)
    # A signal while the jobs are sent ends the sending at once, even a publish that waits on
    # a broker gone silent (:func:`_until_signal`); then every job begun is cancelled
    # (:func:`_cancel_sent`). Raised where it landed, it left a job half sent, its record
    # without its message, "queued" forever; counted, it waited out the broker's reply.
    sending = _Sending()
    with _Interrupts() as intr:
        intr.armed = False
        with farm_errors(celery_app):
            ids = _until_signal(intr, lambda: jobs.submit(paths, opts, render=render, sending=sending.begin))
        if ids is _SIGNALLED or intr.count:
            _cancel_sent(celery_app, sending.stop(), intr, "tween submit")
    for job_id in ids:
        typer.echo(job_id)


class _Sending:
    """The jobs a command sends from a thread: :meth:`begin` (jobs.submit's ``sending``) is
    told each job before anything of it is sent, and refuses once :meth:`stop` is called,
    which returns every job begun: none is begun after it."""

    def __init__(self):
        self.lock, self.begun, self.stopped = threading.Lock(), [], False

    def begin(self, job_id: str) -> bool:
        with self.lock:
            if not self.stopped:
                self.begun.append(job_id)
            return not self.stopped

    def stop(self) -> list[str]:
        with self.lock:
            self.stopped = True
            return list(self.begun)


#: What :func:`_until_signal` returns when the signal came first.
_SIGNALLED = object()


def _until_signal(intr: _Interrupts, fn):
    """Runs ``fn`` in a daemon thread and waits for it or for SIGINT or SIGTERM (one more
    than ``intr`` has counted): ``fn``'s result (its error raised here, unless the signal
    came too), or _SIGNALLED; the thread is then left to end with the process. A publish or
    a result write waits for the server's reply inside the farm client's library, up to
    reply_timeout where the server went silent, and a signal raised there would leave the
    library's connection half used."""
    seen, out = intr.count, []

    def run() -> None:
        try:
            out.append((fn(), None))
        except BaseException as e:  # handed to the waiting thread
            out.append((None, e))

    t = threading.Thread(target=run, name="tween-send", daemon=True)
    t.start()
    while not out and intr.count == seen:
        t.join(0.05)
    if not out or (intr.count != seen and out[0][1] is not None):
        return _SIGNALLED
    value, error = out[0]
    if error is not None:
        raise error
    return value


def _cancel_sent(celery_app, begun: list[str], intr: _Interrupts, command: str) -> None:
    """Cancels the jobs an interrupted ``command`` had begun to send, whatever reached the
    farm of the last (jobs.cancel_sent), says so and exits 130. A second signal while the
    cancel waits on a silent server stops the wait: the jobs are named, not cancelled."""
    from workers.app import farm_errors

    ids = ", ".join(begun)
    if not begun:
        print("tween: interrupted: no job was sent", file=sys.stderr)
        _exit(EXIT_CANCELLED)
    with farm_errors(celery_app, begun):
        done = _until_signal(intr, lambda: _jobs().cancel_sent(begun, why=f"{command} interrupted"))
    if done is _SIGNALLED:
        print(f"tween: interrupted again: the {len(begun)} job(s) it had sent ({ids}) are not cancelled: "
              f"`tween cancel` them once the farm answers", file=sys.stderr)  # fmt: skip
    else:
        print(f"tween: interrupted: cancelled the {len(begun)} job(s) it had sent ({ids})", file=sys.stderr)
    _exit(EXIT_CANCELLED)


def status(
    job_ids: list[str] = typer.Argument(..., help="Job ids from `tween submit`."),
    wait: bool = typer.Option(False, "--wait", help="Wait (with progress bars) until the jobs finish."),
    as_json: bool = typer.Option(False, "--json", help="One JSON object per job."),
):
    """State of farm jobs: queued, running (stage), success (layer paths) or failure (reason)."""
    jobs = _jobs()
    from workers.app import app as celery_app
    from workers.app import check_farm, farm_errors

    job_ids = _job_ids(job_ids)
    check_farm(celery_app, broker=False)  # the states are in the result backend
    fills = [j for j in job_ids if not j.startswith(("rig-", "lib-"))]
    with farm_errors(celery_app):
        by_id = dict(
            zip(fills, jobs.wait(fills) if wait and fills else [jobs.state(j) for j in fills], strict=True)
        )
        for j in job_ids:
            if j.startswith("rig-"):
                by_id[j] = jobs.wait_train_rig(j) if wait else jobs.train_rig_state(j)
            elif j.startswith("lib-"):
                by_id[j] = jobs.wait_library(j) if wait else jobs.library_state(j)
    states = [by_id[j] for j in job_ids]
    code = 0
    for s in states:
        if as_json:
            typer.echo(json.dumps(s.as_dict()))
        elif s.id.startswith("rig-") and s.state == "SUCCESS":
            r = s.result or {}
            typer.echo(
                f"{s.id} {s.shot}: success, model {r.get('out')} ({r.get('model')}, hash {r.get('model_hash')})"
            )
        elif s.id.startswith("lib-") and s.state == "SUCCESS":
            r = s.result or {}
            typer.echo(f"{s.id} {s.shot}: success, {r.get('takes')} take(s), {r.get('hours', 0):.2f} h, "
                       f"hash {r.get('hash')} ({r.get('added')} added, {len(r.get('failed') or [])} failed)")  # fmt: skip
        elif s.id.startswith("lib-") and s.state == "RUNNING":
            typer.echo(f"{s.id} {s.shot}: running {s.stage}")
        elif s.id.startswith("rig-") and s.state == "RUNNING" and (s.result or {}).get("levels"):
            r = s.result
            typer.echo(f"{s.id} {s.shot}: running train-rig, levels {r['levels']}, iteration "
                       f"{r['iteration']}/{r['iterations']} ({100 * r['fraction']:.0f} %)")  # fmt: skip
        elif s.state == "SUCCESS":
            layer = (s.result or {}).get("layer")
            typer.echo(f"{s.id} {s.shot}: success, layer {layer}{_decision(layer)}")
        elif s.state == "UNKNOWN":  # a job id the farm does not know: bad input, said on stderr
            print(f"tween: error: {s.error}", file=sys.stderr)
        elif s.state == "FAILURE":
            typer.echo(f"{s.id} {s.shot}: failure: {s.error}")
        elif s.id.startswith(("rig-", "lib-")):
            typer.echo(
                f"{s.id} {s.shot}: {' '.join(filter(None, (s.state.lower(), s.stage)))} ({s.done}/{s.total} stages)"
            )
        else:
            typer.echo(_status_line(s))
        code = code or (2 if s.state in ("FAILURE", "UNKNOWN", "CANCELLED") else 0)
    raise typer.Exit(code)


def cancel(
    job_ids: list[str] = typer.Argument(..., help="Fill job ids (from `tween submit` or `tween fill`)."),
    wait_s: float = typer.Option(CANCEL_WAIT_S, "--wait", help="Seconds to wait for running stages to stop."),
):
    """Cancel fill jobs on the farm that runs them: queued stages never run (even on a worker
    started later), a running stage stops at its next heartbeat, and nothing the job wrote
    is kept (no new version, no work or review files)."""
    jobs = _jobs()
    from workers.app import app as celery_app
    from workers.app import check_farm, farm_errors

    if not 0 <= wait_s <= 24 * 3600:
        raise TweenError(f"--wait {wait_s:g}: must be from 0 to 86400 seconds")
    job_ids = _job_ids(job_ids)
    check_farm(celery_app, broker=False)  # the records are in the result backend
    bad = [j for j in job_ids if j.startswith(("rig-", "lib-"))]
    if bad:
        raise TweenError(f"{bad[0]}: only fill jobs can be cancelled")
    code = 0
    with farm_errors(celery_app):
        before = jobs.cancel(job_ids, why="tween cancel")
        live = []
        for j in job_ids:
            s = before[j]
            if s.state == "UNKNOWN":
                _err(s.error or f"{j}: no such job")
                code = 2
            elif s.state == "CANCELLED":
                typer.echo(f"{j} {s.shot}: already cancelled")
            elif s.finished:
                _err(f"{j} {s.shot}: already finished ({s.state.lower()}), nothing to cancel")
                code = 2
            else:
                live.append(j)
        for s in _settle(live, timeout=wait_s) if live else []:
            if s.state == "CANCELLED":
                typer.echo(f"{s.id} {s.shot}: cancelled")
            elif s.state == "SUCCESS":
                _err(f"{s.id} {s.shot}: finished before the cancel reached it")
                code = 2
            else:
                _err(f"{s.id} {s.shot}: cancel requested; {s.stage} still stopping (`tween status {s.id}`)")
                code = 2
    raise typer.Exit(code)


def _check_worker_args(queue: str | None, hostname: str | None, include) -> None:
    """What Celery would take and fail on later (an internal error) or never run."""
    from celery.utils.nodenames import host_format

    if queue is not None and not queue.strip():
        raise TweenError(f"--queue {queue!r}: empty (no job is ever sent there)")
    if hostname is not None:
        try:
            host_format(hostname)
        except ValueError as e:
            raise TweenError(f"--hostname {hostname!r}: {str(e).splitlines()[0].rstrip('.')}") from None
    for mod in (m.strip() for arg in include or () for m in arg.split(",")):
        try:
            found = importlib.util.find_spec(mod) is not None
        except (ImportError, ValueError):
            found = False
        if not found:
            raise TweenError(f"--include {mod!r}: no such module on this host's Python path")


def worker(
    concurrency: int = typer.Option(None, "-c", "--concurrency", help="Pool processes (default: CPU count)."),
    queue: str = typer.Option(None, "--queue", "-Q", help="Queue to consume (default: the fill queue)."),
    train: bool = typer.Option(False, "--train", help="Run training jobs (their own queue and limits)."),
    train_rig: bool = typer.Option(
        False, "--train-rig", help="Run per-rig model training jobs (their own queue and limits)."
    ),
    hostname: str = typer.Option(None, "--hostname", "-n", help="Worker name, e.g. node1@%h."),
    loglevel: str = typer.Option("info", "--loglevel", "-l"),
    logfile: Path = typer.Option(None, "--logfile"),
    include: list[str] = typer.Option([], "--include", "-I", help="Extra modules to import."),
):
    """Run a Celery worker for the farm (several may run per host and across hosts)."""

    _int_opt("--concurrency", concurrency, 1, 256)
    levels = ("debug", "info", "warning", "error", "critical", "fatal")
    if loglevel.lower() not in levels:
        raise TweenError(f"--loglevel {loglevel!r}: must be one of {', '.join(levels)}")
    n = concurrency or os.cpu_count() or 1
    # Before any ORT/GL import: each pool process gets its share of the cores.
    for k, v in thread_env(n).items():
        os.environ.setdefault(k, v)
    if train and train_rig:
        raise TweenError("--train and --train-rig are two different workers; start one of each")
    _check_worker_args(queue, hostname, include)
    if train_rig:
        from workers.app import rig_app as celery_app
    elif train:
        from workers.app import train_app as celery_app
    else:
        from workers.app import app as celery_app
    from workers.app import check_farm, for_worker

    s = celery_app.conf.tween
    q = queue or (s.train_rig_queue if train_rig else s.train_queue if train else s.queue)
    # Celery itself would retry an unreachable broker for minutes, logging tracebacks.
    check_farm(celery_app)
    argv = ["worker", "-c", str(n), "-Q", q, "-l", loglevel, "--without-gossip", "--without-mingle"]
    argv += ["--pool", "prefork"]
    if hostname:
        argv += ["-n", hostname]
    if logfile:
        argv += ["--logfile", str(logfile)]
    if include:  # Celery keeps the last -I only: every module in one comma-separated list
        argv += ["-I", ",".join(include)]
    print(f"tween worker: {redact_url(s.broker_url)} queue {q}, {n} processes", file=sys.stderr)
    for_worker(celery_app).worker_main(argv)


def _check_rig_job(source: Path, o: TrainRigOptions) -> None:
    """What the worker's `tween train-rig` would refuse of the clip, refused before the job
    is sent (the options themselves: ``TrainRigOptions.check``): the clip read as the
    training reads it (a USD shot, BVH or .npz; ``--skeleton``, ``--frames`` inside it;
    ``--contacts`` joints of it: pipeline.rig.train's own functions, no model trained)."""
    from pipeline.rig.source import parse_frames
    from pipeline.rig.train import TrainConfig, prepare_motion, spec_for

    cfg = TrainConfig(
        source=str(source), out="", skeleton=o.skeleton, frames=parse_frames(o.frames), fps=o.fps
    )
    spec_for(prepare_motion(cfg), o.contact_joints())


@with_train_rig_options
def submit_train_rig(
    source: Path = typer.Argument(..., help="The reference clip: a USD shot or a BVH, on shared storage."),
    out: str = typer.Option(
        ..., "--out", metavar="PATH", help="Model folder (e.g. models/<rig>); resubmitting resumes."
    ),
    wait: bool = typer.Option(False, "--wait", help="Wait with a progress bar; print the model folder."),
    opts: TrainRigOptions = None,
):
    """Train a per-rig model on the farm's rig training queue (`tween worker --train-rig`);
    prints the job id (`tween status ID` shows its progress)."""
    jobs = _jobs()

    checked = opts.check()
    opts = checked.as_job()
    from workers.app import check_farm, farm_errors, rig_app

    raise_settings_error()
    if rig_app.conf.tween.embedded:
        _err("no broker configured (set TWEEN_BROKER_URL); run `tween train-rig` on this host instead")
        raise typer.Exit(2)
    out = given_path(out, "--out")
    if why := not_a_file(source, "clip file"):  # a pipe said "no such file"
        _err(f"{source}: {why}")
        raise typer.Exit(2)
    _check_rig_job(source, checked)
    if not checked.force:  # as `tween train-rig` refuses it, before a worker takes the job
        refuse_model(out)
    refuse_read_only(out)  # a job the worker could only fail (and only fill jobs are cancelled)
    check_farm(rig_app)
    with farm_errors(rig_app):
        job_id = jobs.submit_train_rig(str(source), str(out), opts)
    if not wait:
        typer.echo(job_id)
        return
    print(job_id, file=sys.stderr)
    with farm_errors(rig_app):
        s = jobs.wait_train_rig(job_id)
    if s.state != "SUCCESS":
        _err(s.error or f"{source}: training {job_id} {s.state.lower()}")
        raise typer.Exit(2)
    r = s.result or {}
    typer.echo(f"{r.get('out')}  ({r.get('model')}, hash {r.get('model_hash')})")


@with_library_options
def submit_library(
    folder: str = typer.Argument(
        ..., metavar="FOLDER", help="Folder of takes (BVH and USD), on storage every worker sees."
    ),
    out: str = typer.Option(
        ..., "--out", metavar="PATH", help="The library folder to write (or to add to, with --add)."
    ),
    wait: bool = typer.Option(False, "--wait", help="Wait, then print the library's summary."),
    opts: LibraryBuildOptions = None,
):
    """Build a motion library on the farm's training queue (`tween worker --train`); prints
    the job id (`tween status ID` shows it)."""
    jobs = _jobs()
    from workers.app import check_farm, farm_errors, train_app

    raise_settings_error()
    if train_app.conf.tween.embedded:
        _err("no broker configured (set TWEEN_BROKER_URL); run `tween library build` on this host instead")
        raise typer.Exit(2)
    from pipeline.library.build import check_out
    from pipeline.usd.take import take_files

    # What `tween library build` refuses is refused here, before a worker takes the job.
    # (A Path made of "" is the working folder: an empty argument is refused as given.)
    folder, out = given_path(folder, "takes folder"), given_path(out, "--out")
    opts.check()
    take_files(folder, opts.include)
    check_out(out, opts.add)
    check_farm(train_app)
    with farm_errors(train_app):
        job_id = jobs.submit_library(str(folder), str(out), opts.as_job())
    if not wait:
        typer.echo(job_id)
        return
    print(job_id, file=sys.stderr)
    with farm_errors(train_app):
        s = jobs.wait_library(job_id)
    if s.state != "SUCCESS":
        _err(s.error or f"{folder}: library job {job_id} {s.state.lower()}")
        raise typer.Exit(2)
    typer.echo(json.dumps(s.result, indent=1))


def bench_farm(
    shots: int = typer.Option(50, "--shots", help="Copies of the example shot to fill."),
    workers: str = typer.Option("1,2", "--workers", help="Worker counts to measure (each -c 1)."),
    shot: Path = typer.Option(None, "--shot", help="Shot to copy (default: the example shot)."),
    out: Path = typer.Option(Path("bench_results") / "farm.json", "--out"),
):
    """Shots per minute with 1 and 2 workers, and Celery's overhead against a direct fill."""
    from workers.bench import run_bench_farm

    _int_opt("--shots", shots, 1, 100_000)
    try:
        counts = [int(w) for w in workers.split(",")]
    except ValueError:
        raise TweenError(f"--workers {workers!r}: expected worker counts, e.g. 1,2") from None
    if not counts or not all(1 <= c <= 64 for c in counts):
        raise TweenError(f"--workers {workers!r}: each worker count must be from 1 to 64")
    res = run_bench_farm(shots, counts, shot, out)
    typer.echo(res["markdown"])
    typer.echo(f"written: {out}", err=True)


def register(app: typer.Typer) -> None:
    """Adds this package's commands to ``app``, in the order ``tween --help`` lists them."""
    app.command()(fill)
    app.command()(submit)
    app.command()(status)
    app.command()(cancel)
    app.command()(worker)
    app.command("submit-train-rig")(submit_train_rig)
    app.command("submit-library")(submit_library)
    app.command("bench-farm")(bench_farm)
