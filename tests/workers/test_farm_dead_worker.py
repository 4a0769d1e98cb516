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
from redis_server import REPO, WorkerPool, copy_shot, example_shot, farm_env, leftovers, start_redis

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
    from workers.app import app, configure
    from workers.settings import load_settings

    old = app.conf.tween
    configure(app, load_settings({**os.environ, **env}))
    try:
        yield SimpleNamespace(server=server, root=root, env=env, logs=logs, app=app)
    finally:
        configure(app, old)
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
