"""A worker SIGKILLed in the middle of a review render, on a real Redis farm: the render's
lease was renewed while it ran (longer than the visibility timeout, no second worker got
it), `tween status` says the worker is lost and when the broker requeues the stage, then
that it was requeued; the worker that takes it over removes the dead one's scratch."""

from __future__ import annotations

import os
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
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

# Test-sized timings: takeover VT + RESTORE after the last heartbeat (HB); a stage with no
# heartbeat for 3 × HB is shown as lost.
VT, RESTORE, HB, HARD, SOFT = 8, 1, 1, 7, 6
FRAME_DELAY = 0.3  # seconds per written frame of the slowed render (97 frames, 2 writer threads)


@pytest.fixture(scope="module")
def farm(tmp_path_factory):
    server = start_redis()
    root = tmp_path_factory.mktemp("shots")
    logs = tmp_path_factory.mktemp("logs")
    env = farm_env(server, [str(root)], TWEEN_VISIBILITY_TIMEOUT=VT, TWEEN_RESTORE_INTERVAL=RESTORE,
                   TWEEN_HEARTBEAT_INTERVAL=HB, TWEEN_FILL_TIME_LIMIT=HARD, TWEEN_FILL_SOFT_TIME_LIMIT=SOFT)  # fmt: skip
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), str(REPO / "tests")])
    from workers.app import app
    from workers.settings import load_settings

    old = app.conf.tween
    configure_app(app, load_settings({**os.environ, **env}))
    try:
        yield SimpleNamespace(server=server, root=root, env=env, logs=logs, app=app)
    finally:
        configure_app(app, old)
        server.cleanup()


def _status(job_id: str) -> str:
    from typer.testing import CliRunner

    from pipeline.cli import app as cli

    return CliRunner().invoke(cli, ["status", job_id]).stdout


def test_worker_killed_in_the_render_is_seen_requeued_and_cleaned(farm, tmp_path):
    from workers import jobs

    markers = tmp_path / "markers"
    markers.mkdir()
    pool = WorkerPool(farm.env, farm.logs)
    try:
        a = pool.start(concurrency=1, include=["farm_slowrender"], TWEEN_TEST_MARKERS=markers,
                       TWEEN_TEST_FRAME_DELAY=FRAME_DELAY)  # fmt: skip
        pool.wait_ready()
        folder = farm.root / "dead"
        shot = copy_shot(example_shot(), folder, "dead")
        out = folder / "out"
        (job,) = jobs.submit([str(shot)], jobs.make_opts(takes=1, seed=7, out_dir=str(out)), render=True)
        t0 = time.monotonic()
        while not any(markers.iterdir()):
            assert time.monotonic() - t0 < 90, "the render never started"
            time.sleep(0.1)
        t_render = time.monotonic()
        b = pool.start(concurrency=1)  # idle, on the same queue
        pool.wait_ready()
        # The render runs past VT + restore: its lease is renewed, B is not handed it.
        time.sleep(max(0.0, t_render + VT + RESTORE + 3 - time.monotonic()))
        assert f"{job}.review] received" not in b.log_text()
        (scratch,) = (out / "review").glob(".tween-review-*")
        assert scratch.name.startswith(f".tween-review-{job}.") and any(scratch.glob("*.png"))
        assert "running review" in _status(job)
        a.kill_host()
        t_kill = time.monotonic()
        lost = requeued = None
        while True:
            line = _status(job)
            if "worker lost" in line and lost is None:
                lost = (time.monotonic() - t_kill, line)
            if "requeued at" in line:
                requeued = line
            s = jobs.state(job)
            if s.finished:
                break
            assert time.monotonic() - t_kill < VT + RESTORE + 60, line
            time.sleep(0.25)
        print(f"\nlost shown {lost[0]:.1f} s after the kill: {lost[1]}requeued: {requeued}")
        assert s.state == "SUCCESS", s.error
        assert a.name in lost[1] and "requeues it by" in lost[1] and "in stage review" in lost[1]
        assert lost[0] < 3 * HB + 3
        assert requeued is not None and f"after worker {a.name}" in requeued
        assert f"{job}.review] received" in b.log_text()
        assert f"removed {scratch}" in b.log_text()  # by the worker that took the stage over
        assert not scratch.exists() and not list((out / "review").glob(".tween-review-*"))
        mp4 = Path(s.result["renders"][0]["mp4"])
        assert mp4.is_file() and mp4.stat().st_size > 10_000
        assert sorted(p.name for p in out.glob("*.usd*")) == ["dead.review.v001.usda", "dead.tween.v001.usda"]
        assert leftovers(folder) == []
    finally:
        pool.stop_all()


def test_a_killed_embedded_fill_is_undone_by_the_next_run(tmp_path):
    """`kill -9` of an embedded `tween fill` in its render takes its worker with it; the next
    run of the shot removes what the dead job wrote (its version, scratch and work folder),
    and a render removes the scratch of any dead writer on its host."""
    import signal
    import subprocess
    import sys

    from embedded_farm import embedded_env

    from pipeline.usd.files import HOST as _HOST

    markers = tmp_path / "markers"
    markers.mkdir()
    env = embedded_env(
        tmp_path, slow=("farm_slowrender",), TWEEN_TEST_MARKERS=markers, TWEEN_TEST_FRAME_DELAY=0.2
    )
    shots = tmp_path / "shots"
    shot = copy_shot(example_shot(), shots, "killed")
    cmd = [sys.executable, "-m", "pipeline.cli", "fill", str(shot), "--render", "--no-progress"]
    proc = subprocess.Popen(cmd, env=env, cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        t0 = time.monotonic()
        while not any(markers.iterdir()):
            assert proc.poll() is None and time.monotonic() - t0 < 90
            time.sleep(0.05)
        time.sleep(0.5)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    time.sleep(1.0)  # its worker and pool die with it (PR_SET_PDEATHSIG)
    (scratch,) = (shots / "review").glob(".tween-review-*")
    (work,) = (shots / ".tween-work").iterdir()
    assert (shots / "killed.tween.v001.usda").is_file() and any(scratch.glob("*.png"))
    # A scratch some other writer on this host left when it died (a `tween review` killed).
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    other = shots / "review" / f".tween-review-local.{int(dead.stdout)}@{_HOST}.x1.tmp"
    other.mkdir()
    env.pop("TWEEN_TEST_SLOW_MODULES")
    res = subprocess.run(cmd, env=env, cwd=tmp_path, capture_output=True, text=True, timeout=180)
    assert res.returncode == 0, res.stderr[-3000:]
    job = scratch.name.split(".")[1].removeprefix("tween-review-")
    assert (
        f"tween: removed job {job} of {shot}, left unfinished by a tween fill that was killed" in res.stderr
    )
    assert not scratch.exists() and not work.exists() and not other.exists()
    assert not list((shots / "review").glob(".tween-review-*"))
    # One version: the new run's (the dead job's v001 went, so it is v001 again).
    assert sorted(p.name for p in shots.glob("*.usd*")) == [
        "killed.review.v001.usda",
        "killed.tween.v001.usda",
        "killed.usda",
    ]
    assert sorted(p.name for p in (shots / "review").iterdir() if not p.name.endswith(".png")) == [
        "killed_v001.mp4",
        "killed_v001.otio",
    ]
    assert leftovers(shots) == []


def test_a_beat_is_judged_by_its_own_workers_interval(monkeypatch):
    """A worker beating every 20 s was shown "lost" after 7 s by a client whose own setting
    was 2 s (and `tween cancel` undid its files while it still ran): each beat records its
    worker's interval, and silence counts against that."""
    from workers import control, jobs

    now = time.time()
    beat = {"time": now - 30, "worker": "w@h", "host": "h", "pid": 1, "ended": False}
    monkeypatch.setattr(control, "record", lambda meta, state: dict(beat))
    monkeypatch.setattr(jobs, "_meta", lambda tid: {})
    for interval, lost in ((20, False), (5, True), (None, True)):  # None: a beat before the key
        beat.pop("interval", None)
        if interval is not None:
            beat["interval"] = interval
        js = jobs.JobState(id="j")
        jobs._heartbeats(js, [("take0", "j.take0")])
        assert (js.lost is not None) == lost, (interval, js.lost)
    assert control.dead_after(SimpleNamespace(heartbeat_interval=2), {"interval": True}) == 6.0
