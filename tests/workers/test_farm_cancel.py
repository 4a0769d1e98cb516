"""Cancel means cancel: Ctrl-C (SIGINT) or SIGTERM on `tween fill`, and `tween cancel JOB`,
stop the job on the farm that runs it, at whatever point it is; exit status 130; no version
appears, then or later (a worker started after the cancel does not run it), and nothing is
left in the shot's, work or review folders. On the embedded farm and on Redis with a real
worker; the fill and the render are slowed (tests/farm_slowfill.py, farm_slowrender.py) so
that the signal lands in the stage named."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path
from types import SimpleNamespace

import pytest
from embedded_farm import embedded_env, worker_log
from redis_server import (
    REPO,
    WorkerPool,
    configure_app,
    copy_shot,
    example_shot,
    farm_env,
    leftovers,
    start_redis,
)

from workers import cli as fill_cli

SLOW = dict(TWEEN_TEST_FILL_DELAY=3, TWEEN_TEST_FRAME_DELAY=0.2)


def _wait_for(path_glob, folder, timeout=90, proc=None):
    t0 = time.monotonic()
    while not list(folder.glob(path_glob)):
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"exited early ({proc.returncode}): {proc.stderr.read()[-3000:]}")
        assert time.monotonic() - t0 < timeout, f"no {path_glob} in {folder} after {timeout} s"
        time.sleep(0.05)


def _only_the_shot(folder, name):
    """Nothing but the shot: no version, no review folder or scratch, no .tween-work."""
    assert sorted(p.name for p in folder.iterdir()) == [name], sorted(str(p) for p in folder.rglob("*"))


@pytest.mark.parametrize(
    "point, sig, marker",
    [("take", signal.SIGINT, "*.take0"), ("render", signal.SIGTERM, "*.render")],
)
def test_interrupted_embedded_fill_cancels_its_job(tmp_path, point, sig, marker):
    markers = tmp_path / "markers"
    markers.mkdir()
    env = embedded_env(
        tmp_path, slow=("farm_slowfill", "farm_slowrender"), TWEEN_TEST_MARKERS=markers, **SLOW
    )
    shots = tmp_path / "shots"
    shot = copy_shot(example_shot(), shots, "cancel")
    cmd = [
        sys.executable,
        "-m",
        "pipeline.cli",
        "fill",
        str(shot),
        "--takes",
        "2",
        "--render",
        "--no-progress",
    ]
    proc = subprocess.Popen(
        cmd, env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        _wait_for(marker, markers, proc=proc)
        time.sleep(0.5)
        if point == "render":  # its scratch holds frames now
            assert list((shots / "review").glob(".tween-review-*/*.png"))
        t_sig = time.monotonic()
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            proc.kill()
    took = time.monotonic() - t_sig
    assert proc.returncode == 130, err[-3000:]
    print(f"\n{point}: {signal.Signals(sig).name} to exit {took:.1f} s")
    assert out == ""
    assert "tween: interrupted: cancelling 1 job(s)" in err and "cancelled by" in err
    assert "nothing of it kept" in err
    _only_the_shot(shots, "cancel.usda")
    log = worker_log(tmp_path)
    stage = "take0" if point == "take" else "review"
    assert f"{stage}] raised expected: JobCancelledError" in log or f"{stage}] raised" in log, log[-3000:]
    # Stopped with it: the embedded worker and its pool (given a few seconds on a loaded machine).
    t0 = time.monotonic()
    while _worker_pids(tmp_path) and time.monotonic() - t0 < 15:
        time.sleep(0.2)
    assert not _worker_pids(tmp_path)


def test_an_embedded_worker_that_dies_is_one_line_and_its_job_is_undone(tmp_path):
    """The embedded worker killed mid-take: the fill said so in 16 lines (Celery's log tail),
    left its version layers and scratch beside the shot, and `tween status` promised a requeue
    that never came (the private queue is gone). Now: one line, the job cancelled and undone."""
    markers = tmp_path / "markers"
    markers.mkdir()
    env = embedded_env(tmp_path, slow=("farm_slowfill",), TWEEN_TEST_MARKERS=markers, **SLOW)
    shots = tmp_path / "shots"
    shot = copy_shot(example_shot(), shots, "dies")
    cmd = [sys.executable, "-m", "pipeline.cli", "fill", str(shot), "--takes", "2", "--no-progress"]
    proc = subprocess.Popen(
        cmd, env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        _wait_for("*.take0", markers, proc=proc)
        for pid in _worker_pids(tmp_path):
            if pid != proc.pid:
                os.kill(pid, signal.SIGKILL)
        out, err = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 2 and out == "", err[-3000:]
    (line,) = err.splitlines()
    assert line.startswith("tween: error: the embedded worker was killed (signal 9); its log: "), line
    assert line.endswith("1 unfinished job(s) cancelled, nothing of them kept"), line
    _only_the_shot(shots, "dies.usda")


def _worker_pids(tmp_path) -> list[int]:
    """Pids of this run's processes still there (the embedded worker and its pool): any
    process whose environment names the run's cache folder."""
    out = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/environ", "rb") as f:
                    if str(tmp_path / "cache").encode() in f.read():
                        out.append(int(d))
            except OSError:
                continue
    return out


# --- Redis, real workers ------------------------------------------------------------------


@pytest.fixture(scope="module")
def farm(tmp_path_factory):
    server = start_redis()
    root = tmp_path_factory.mktemp("shots")
    logs = tmp_path_factory.mktemp("logs")
    markers = tmp_path_factory.mktemp("markers")
    env = farm_env(server, [str(root)], TWEEN_VISIBILITY_TIMEOUT=16, TWEEN_RESTORE_INTERVAL=2,
                   TWEEN_FILL_TIME_LIMIT=14, TWEEN_FILL_SOFT_TIME_LIMIT=12, TWEEN_HEARTBEAT_INTERVAL=1)  # fmt: skip
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), str(REPO / "tests")])
    from workers.app import app
    from workers.settings import load_settings

    old = app.conf.tween
    configure_app(app, load_settings({**os.environ, **env}))
    pool = WorkerPool(env, logs)
    try:
        yield SimpleNamespace(server=server, root=root, env=env, pool=pool, markers=markers, app=app)
    finally:
        pool.stop_all()
        configure_app(app, old)
        server.cleanup()


def _cli(*args):
    from typer.testing import CliRunner

    from pipeline.cli import app as cli

    return CliRunner().invoke(cli, list(args))


def _worker(farm):
    """The module's worker (slowed fill and render), started on first use."""
    if not farm.pool.workers:
        farm.pool.start(concurrency=1, include=["farm_slowfill", "farm_slowrender"],
                        TWEEN_TEST_MARKERS=farm.markers, **SLOW)  # fmt: skip
        farm.pool.wait_ready()
    return farm.pool.workers[0]


def test_cancelled_before_any_worker_runs_on_no_worker_started_later(farm):
    from workers import jobs

    assert not farm.pool.workers  # the farm has no worker yet: the job waits in the queue
    folder = farm.root / "queued"
    shot = copy_shot(example_shot(), folder, "queued")
    (job,) = jobs.submit([str(shot)], jobs.make_opts(takes=2, out_dir=str(folder / "out")), render=True)
    res = _cli("cancel", job)
    assert res.exit_code == 0 and res.stdout == f"{job} {shot}: cancelled\n", res.output
    res = _cli("status", job)
    assert res.exit_code == 2 and f"{job} {shot}: cancelled by " in res.stdout
    w = _worker(farm)  # started after the cancel: it gets the job's first stage and drops it
    t0 = time.monotonic()
    while f"{job}.validate] raised" not in w.log_text():
        assert time.monotonic() - t0 < 30, w.log_text()[-2000:]
        time.sleep(0.1)
    time.sleep(1.0)
    assert f"{job}.take0] received" not in w.log_text()
    assert jobs.state(job).state == "CANCELLED"
    _only_the_shot(folder, "queued.usda")
    # Cancelling again says so; a job that is not there is one line, exit 2.
    assert _cli("cancel", job).stdout == f"{job} {shot}: already cancelled\n"
    res = _cli("cancel", "0" * 32)
    assert res.exit_code == 2


def test_tween_cancel_stops_a_running_render(farm):
    from workers import jobs

    w = _worker(farm)
    folder = farm.root / "running"
    shot = copy_shot(example_shot(), folder, "running")
    for m in farm.markers.iterdir():
        m.unlink()
    (job,) = jobs.submit([str(shot)], jobs.make_opts(takes=1, out_dir=str(folder / "out")), render=True)
    _wait_for("*.render", farm.markers)
    assert list((folder / "out").glob("running.tween.v001.usd*"))  # the layers were written
    t0 = time.monotonic()
    res = _cli("cancel", job)
    took = time.monotonic() - t0
    assert res.exit_code == 0 and res.stdout == f"{job} {shot}: cancelled\n", res.output
    print(f"\ntween cancel of a running render: {took:.1f} s")
    assert took < 10
    assert f"{job}.review] raised expected: JobCancelledError" in w.log_text()
    _only_the_shot(folder, "running.usda")
    assert leftovers(folder) == []


def test_ctrl_c_on_a_farm_fill_cancels_its_job(farm, tmp_path):
    from workers import jobs

    _worker(farm)
    folder = farm.root / "client"
    shot = copy_shot(example_shot(), folder, "client")
    for m in farm.markers.iterdir():
        m.unlink()
    env = {k: v for k, v in os.environ.items() if not k.startswith("TWEEN_")}
    env.update(farm.env)
    cmd = [
        sys.executable,
        "-m",
        "pipeline.cli",
        "fill",
        str(shot),
        "--takes",
        "2",
        "--render",
        "--no-progress",
    ]
    proc = subprocess.Popen(
        cmd, env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        _wait_for("*.take*", farm.markers, proc=proc)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err[-3000:]
    assert "cancelled by" in err and out == ""
    job = err.split("cancelling 1 job(s) (", 1)[1].split(")", 1)[0]
    assert jobs.state(job).state == "CANCELLED"
    _only_the_shot(folder, "client.usda")


def test_a_fill_whose_job_is_cancelled_elsewhere_exits_130(farm, tmp_path):
    _worker(farm)
    folder = farm.root / "elsewhere"
    shot = copy_shot(example_shot(), folder, "elsewhere")
    env = {k: v for k, v in os.environ.items() if not k.startswith("TWEEN_")}
    env.update(farm.env)
    cmd = [sys.executable, "-m", "pipeline.cli", "fill", str(shot), "--takes", "2", "--no-progress"]
    proc = subprocess.Popen(
        cmd, env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        _wait_for(".tween-work/*", folder, proc=proc)  # the job's work folder is named after it
        (work,) = (folder / ".tween-work").iterdir()
        res = _cli("cancel", work.name)
        assert res.exit_code == 0 and res.stdout == f"{work.name} {shot}: cancelled\n", res.output
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err[-3000:]
    assert f"tween: {shot}: job {work.name} cancelled by " in err and out == ""
    assert "tween: interrupted" not in err  # it was not: its job was cancelled elsewhere
    _only_the_shot(folder, "elsewhere.usda")


def test_an_interrupted_submit_cancels_the_jobs_it_sent(farm, monkeypatch):
    """SIGINT while `tween submit` sends its jobs: it raised where it landed, so the jobs sent
    stayed queued with no id printed (one record without its message, "queued" forever)."""
    from workers import jobs

    real = jobs.submit

    def submit_then_interrupted(*a, **k):
        ids = real(*a, **k)
        os.kill(os.getpid(), signal.SIGINT)  # counted by the handler: the sending goes on
        time.sleep(0.05)
        return ids

    monkeypatch.setattr(jobs, "submit", submit_then_interrupted)
    folder = farm.root / "submitted"
    shots = [copy_shot(example_shot(), folder, f"sub{i}") for i in range(2)]
    res = _cli("submit", *map(str, shots))
    assert res.exit_code == 130 and res.stdout == "", res.output
    (line,) = res.stderr.splitlines()
    assert line.startswith("tween: interrupted: cancelled the 2 job(s) it had sent ("), line
    ids = line.rsplit("(", 1)[1].rstrip(")").split(", ")
    assert len(ids) == 2 and all(jobs.control.cancel_record(farm.app, j) for j in ids)


def test_cancel_of_a_finished_job_is_one_line(farm, monkeypatch):
    from workers import jobs

    done = jobs.JobState(id="f" * 32, shot="/x/sh.usda", state="SUCCESS")
    monkeypatch.setattr(jobs, "state", lambda j: done)
    res = _cli("cancel", done.id)
    assert res.exit_code == 2
    assert (
        res.stderr == f"tween: error: {done.id} /x/sh.usda: already finished (success), nothing to cancel\n"
    )
    assert jobs.control.cancel_record(farm.app, done.id) is None  # nothing was written


def _running(ids) -> dict:
    """A fake ``jobs.cancel``'s answer: each job still ran when it was cancelled."""
    from workers.jobs import JobState

    return {j: JobState(id=j, shot="/s/sh.usda", state="RUNNING") for j in ids}


def _all_cancelled(ids, intr, alive) -> list:
    """A fake ``_settle``: each job stopped, cancelled."""
    from workers.jobs import JobState

    return [JobState(id=j, shot="/s/sh.usda", state="CANCELLED") for j in ids]


def _closing_turns_it_into(error: Exception):
    """What SQLAlchemy did when the interrupt landed inside its connection close: a cleanup
    that fails while the interrupt is being raised, so the interrupt is the error's context."""

    def wait(*a, **k):
        try:
            raise fill_cli._Interrupted()
        finally:
            raise error

    return wait


def test_an_interrupt_a_library_turns_into_its_own_error_still_cancels(monkeypatch, capsys):
    """The handler raises where the signal lands; a library cleaning up there (the SQLite
    farm's result store closing a connection) may raise its own error instead, with the
    interrupt as its context. That is still the interrupt: the jobs are cancelled, 130. An
    error with no interrupt behind it stays an error."""
    calls = []
    jobs = SimpleNamespace(
        wait=_closing_turns_it_into(AssertionError()),
        cancel=lambda ids, why: calls.append(("cancel", tuple(ids), why)) or _running(ids),
    )
    monkeypatch.setattr(fill_cli, "_jobs", lambda: jobs)
    monkeypatch.setattr(fill_cli, "_settle", _all_cancelled)
    intr = fill_cli._Interrupts()
    assert fill_cli._run_jobs(["j1"], intr, progress=False) == fill_cli.EXIT_CANCELLED
    assert calls == [("cancel", ("j1",), "tween fill interrupted")] and not intr.armed
    assert "interrupted: cancelling 1 job(s) (j1)" in capsys.readouterr().err
    jobs.wait = lambda *a, **k: (_ for _ in ()).throw(AssertionError("a bug"))
    with pytest.raises(AssertionError, match="a bug"):
        fill_cli._run_jobs(["j2"], fill_cli._Interrupts(), progress=False)
    assert len(calls) == 1


def test_an_interrupt_while_waiting_is_raised_by_the_next_poll_not_where_it_lands(monkeypatch, capsys):
    """While the fill waits, the signal lands inside the farm client's library code. Raised
    there, it was lost inside a garbage collector's callback (CI: the fill ran on to exit 0),
    and inside a read of the SQLite result store it left the statement holding its lock, so
    the cancel record waited out the store's busy timeouts (CI: no exit within 90 s). So the
    handler returns normally there, and the next poll raises it: the jobs are cancelled, 130."""
    calls, polls = [], []

    def wait(ids, progress, alive):
        intr._handler(signal.SIGINT, None)  # returns: whatever it landed in goes on intact
        for _ in range(3):
            polls.append(1)
            alive()
        return []

    jobs = SimpleNamespace(wait=wait, cancel=lambda ids, why: calls.append(tuple(ids)) or _running(ids))
    monkeypatch.setattr(fill_cli, "_jobs", lambda: jobs)
    monkeypatch.setattr(fill_cli, "_settle", _all_cancelled)
    intr = fill_cli._Interrupts()
    assert fill_cli._run_jobs(["j1"], intr, progress=False) == fill_cli.EXIT_CANCELLED
    assert calls == [("j1",)] and len(polls) == 1
    assert "interrupted: cancelling 1 job(s) (j1)" in capsys.readouterr().err

    # In the last poll, after which wait returned: still the interrupt.
    def wait_then_return(ids, progress, alive):
        intr._handler(signal.SIGTERM, None)
        return []

    jobs.wait = wait_then_return
    intr = fill_cli._Interrupts()
    assert fill_cli._run_jobs(["j2"], intr, progress=False) == fill_cli.EXIT_CANCELLED
    assert calls[-1] == ("j2",)


def _job_at_review(app, tmp_path) -> tuple[str, str, Path]:
    """A one-take job on ``app``'s result store whose stages have run up to its review,
    which runs; its layer written. Returns the job id, its shot and its layer."""
    from workers import jobs
    from workers.app import SUBMITTED

    shot, layer = tmp_path / "sh.usda", tmp_path / "sh.tween.v001.usda"
    shot.write_text("#usda 1.0\n")
    layer.write_text("#usda 1.0\n")
    job = uuid.uuid4().hex
    rec = {"shot": str(shot), "takes": 1, "render": False, "out_dir": "", "made_dirs": [],
           "work_dir": str(tmp_path / ".tween-work" / job)}  # fmt: skip
    app.backend.store_result(job, rec, SUBMITTED)
    for _, tid in jobs.stage_ids(job, 1)[:-1]:
        app.backend.store_result(tid, {}, "SUCCESS")
    app.backend.store_result(f"{job}.review", None, "STARTED")
    return job, str(shot), layer


def _review_ends(app, job: str, layer: Path, how: str) -> None:
    """The job's review stage ends, as its worker ends it: done, or cancelled (undone)."""
    if how == "SUCCESS":
        app.backend.store_result(f"{job}.review", {"layer": str(layer)}, "SUCCESS")
    else:
        layer.unlink()
        app.backend.mark_as_failure(f"{job}.review", RuntimeError("cancelled"))


def test_an_interrupt_once_the_fill_has_finished_cancels_nothing_and_exits_0(embedded_app, tmp_path, monkeypatch,
                                                                             capsys):  # fmt: skip
    """SIGINT in the wait's last poll, every job done: the fill said "interrupted: cancelling",
    reported the job, kept its version and exited 130, so a script that retries on failure
    made a v002. Nothing was cancelled: the job is reported and the status is its own, 0."""
    from workers import control, jobs

    job, shot, layer = _job_at_review(embedded_app, tmp_path)
    _review_ends(embedded_app, job, layer, "SUCCESS")
    real_wait = jobs.wait

    def wait(ids, progress, alive):
        states = real_wait(ids, progress=progress, alive=alive)
        intr._handler(signal.SIGINT, None)  # it lands as the last poll returns
        return states

    monkeypatch.setattr(jobs, "wait", wait)
    intr = fill_cli._Interrupts()
    assert fill_cli._run_jobs([job], intr, progress=False) == 0
    out, err = capsys.readouterr()
    assert out.startswith(f"{shot}: layer {layer}") and layer.is_file()
    assert err.splitlines()[-1] == fill_cli.NOTHING_CANCELLED and "cancelling" not in err
    assert control.cancel_record(embedded_app, job) is None


@pytest.mark.parametrize(("how", "code"), [("SUCCESS", 0), ("CANCELLED", 130)])
def test_an_interrupt_whose_cancel_comes_too_late_exits_0(
    embedded_app, tmp_path, monkeypatch, capsys, how, code
):
    """The cancel written while the job's last stage ran, which then ended before it read it:
    the version is kept and reported, so the fill exits 0 (it was 130). Cancelled in time,
    nothing is kept and it is 130, as ever."""
    from workers import control, jobs

    job, shot, layer = _job_at_review(embedded_app, tmp_path)
    real_cancel = jobs.cancel

    def wait(ids, progress, alive):
        intr._handler(signal.SIGTERM, None)
        alive()  # raises the interrupt, between two reads

    def cancel(ids, why):
        before = real_cancel(ids, why)  # the review still runs: its cancel record is written
        _review_ends(embedded_app, job, layer, how)
        return before

    monkeypatch.setattr(jobs, "wait", wait)
    monkeypatch.setattr(jobs, "cancel", cancel)
    intr = fill_cli._Interrupts()
    assert fill_cli._run_jobs([job], intr, progress=False) == code
    out, err = capsys.readouterr()
    assert f"tween: interrupted: cancelling 1 job(s) ({job})" in err
    assert control.cancel_record(embedded_app, job) is not None
    if how == "SUCCESS":
        assert out.startswith(f"{shot}: layer {layer}") and layer.is_file()
        assert err.splitlines()[-1] == fill_cli.NOTHING_CANCELLED
    else:
        assert out == "" and f"tween: {shot}: job {job} cancelled by " in err
        assert "nothing cancelled" not in err


def _slow_stopping_worker(self, worker: list) -> None:
    """An embedded worker whose warm stop (SIGTERM) takes 3 s, as Celery's took 4-6 s."""
    script = "trap 'sleep 3; exit 0' TERM; echo ready; while :; do sleep 0.05; done"
    self.proc = subprocess.Popen(["sh", "-c", script], start_new_session=True, stdout=subprocess.PIPE)
    worker.append(self.proc)
    assert self.proc.stdout.readline() == b"ready\n"


def test_the_embedded_worker_of_a_finished_fill_is_killed_not_stopped_warm(tmp_path, monkeypatch, capsys):
    """The jobs reported, the embedded worker was stopped warm: about 6 s of Celery's pool and
    thread joins before the fill exited, a Ctrl-C then counted and ignored. Every job having
    ended, it is idle: its process group is killed at once, the jobs kept."""
    from workers import embedded
    from workers.jobs import JobState

    shot = str(tmp_path / "sh.usda")
    worker: list = []

    def enter(self):
        _slow_stopping_worker(self, worker)
        return self

    done = JobState(id="j1", shot=shot, state="SUCCESS", result={"layer": f"{shot}.v001"})
    jobs = SimpleNamespace(submit=lambda *a, **k: ["j1"], wait=lambda ids, progress, alive: [done])
    monkeypatch.setattr(fill_cli, "_jobs", lambda: jobs)
    monkeypatch.setattr(embedded.EmbeddedWorker, "__enter__", enter)
    monkeypatch.setattr(embedded.EmbeddedWorker, "_drop_queue", lambda self, quiet=False: None)
    t0 = time.monotonic()
    assert fill_cli._run_embedded([shot], {}, False, 1, False) == 0
    took = time.monotonic() - t0
    out, err = capsys.readouterr()
    assert out.startswith(f"{shot}: layer {shot}.v001") and "interrupted" not in err
    assert took < 1.5, took
    (proc,) = worker
    assert proc.returncode == -signal.SIGKILL and not _group_left(proc.pid)  # nothing of it left


def test_a_signal_while_the_embedded_worker_stops_warm_ends_it_at_once(monkeypatch):
    """A worker stopped warm (its client's wait ended in an error, jobs may still run) was
    waited for up to 20 s, a Ctrl-C then ignored; the signal (``hurry``) now kills its
    process group at once."""
    from workers import embedded

    signalled: list = []
    w = embedded.EmbeddedWorker(["/tmp"], hurry=lambda: bool(signalled))
    worker: list = []
    _slow_stopping_worker(w, worker)
    threading.Timer(0.3, lambda: signalled.append(1)).start()
    t0 = time.monotonic()
    w._stop()
    took = time.monotonic() - t0
    assert 0.25 < took < 1.5, took
    (proc,) = worker
    assert proc.returncode == -signal.SIGKILL and not _group_left(proc.pid)


def _group_left(pgid: int, within: float = 2.0) -> list[int]:
    """The group's live processes once they have had ``within`` s to die: a SIGKILL to a
    group ends its other members a moment after the leader is reaped, later on a loaded
    machine (seen: a member still listed right after, one run in three beside other tests)."""
    end = time.monotonic() + within
    while (left := _group_members(pgid)) and time.monotonic() < end:
        time.sleep(0.02)
    return left


def _group_members(pgid: int) -> list[int]:
    """The live (not zombie) processes of process group ``pgid``."""
    out = []
    for d in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{d}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()  # state, ppid, pgrp, …
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            out.append(int(d))
    return out


def test_a_worker_names_the_queues_it_takes(farm):
    """What `tween fill`'s no-worker notice asks: the module's worker takes the farm's queue."""
    from workers import jobs

    _worker(farm)
    queue = farm.app.conf.task_default_queue
    assert jobs.unserved_queues([queue, "nobody-takes-this"]) == ["nobody-takes-this"]
