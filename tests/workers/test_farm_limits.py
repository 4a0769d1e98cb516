"""Each stage has its own time limits: the fill's, and the review render's, sized by the work
(frames × takes) and carried by the render's message. A render that hits its soft limit says
which limit and how to raise it; one killed at its hard limit is undone by the worker's main
process. Either way the job leaves nothing: no version, no media, no scratch."""

from __future__ import annotations

import os
import subprocess
import sys
import time
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


def _settings(**env):
    from workers.settings import load_settings

    return load_settings({"TWEEN_FARM_CONFIG": os.devnull, **{k: str(v) for k, v in env.items()}})


def test_render_limits_scale_with_frames_and_takes():
    from workers.limits import render_limit_message, render_limits

    s = _settings()
    assert (s.render_soft_time_limit, s.render_time_limit, s.render_frame_ms) == (100, 120, 250)
    # The shot: 60 s at 30 fps, 3 takes: 5400 frames at 250 ms = 1350 s more.
    assert render_limits(1800, 3, s) == (1450, 1470)
    assert render_limits(97, 1, s) == (125, 145)
    assert render_limits(1800, 3, _settings(TWEEN_RENDER_FRAME_MS=100)) == (640, 660)
    msg = render_limit_message(
        "/shows/sh010.usda", "soft", 1800, 3, s, env={"TWEEN_FARM_CONFIG": "/etc/farm.toml"}
    )
    assert msg == (
        "review render of /shows/sh010.usda hit the farm's soft time limit of 1450 s (render_soft_time_limit "
        "= 100 s + render_frame_ms = 250 ms × 1800 frames × 3 take(s)); raise render_frame_ms or "
        "render_soft_time_limit in /etc/farm.toml or TWEEN_RENDER_FRAME_MS / TWEEN_RENDER_SOFT_TIME_LIMIT "
        "where the job is submitted"
    )


def test_hard_limit_messages_name_the_stage_that_hit_it():
    from celery.exceptions import TimeLimitExceeded

    from workers.limits import failure_message

    s = _settings()
    render = failure_message(
        TimeLimitExceeded(1470), "sh.usda", s, stage="review", work={"frames": 1800, "takes": 3}
    )
    assert "review render of sh.usda hit the farm's hard time limit of 1470 s" in render
    assert "TWEEN_RENDER_TIME_LIMIT" in render
    fill = failure_message(TimeLimitExceeded(50), "sh.usda", s, stage="take 1/2")
    assert "fill of sh.usda hit the farm's hard time limit (fill_time_limit = 50 s)" in fill


def test_a_training_past_its_limit_names_the_setting():
    from celery.exceptions import SoftTimeLimitExceeded, TimeLimitExceeded

    from workers import jobs

    s = _settings()
    for exc in (TimeLimitExceeded(43200), SoftTimeLimitExceeded()):
        backend = SimpleNamespace(
            get_task_meta=lambda tid, exc=exc: {"status": "FAILURE", "result": exc},
            exception_to_python=lambda r: r,
        )
        js = jobs._long_job_state(SimpleNamespace(backend=backend, conf=SimpleNamespace(tween=s)),
                                  "lib-1", "library build", "library job")  # fmt: skip
        assert js.state == "FAILURE"
        assert js.error.startswith(
            "library build lib-1 hit the farm's time limit (train_time_limit = 43200 s;"
        )
        assert "or TWEEN_TRAIN_TIME_LIMIT" in js.error


@pytest.mark.parametrize(
    "env, line",
    [
        ({"TWEEN_RENDER_SOFT_TIME_LIMIT": 130}, "render_soft_time_limit (130 s) must be below render_time_limit (120 s)"),
        ({"TWEEN_RENDER_FRAME_MS": "fast"}, "TWEEN_RENDER_FRAME_MS: expected an integer, got 'fast'"),
        ({"TWEEN_HEARTBEAT_INTERVAL": 0}, "TWEEN_HEARTBEAT_INTERVAL: must be 1 or more, got 0"),
        ({"TWEEN_BROKER_URL": "redis://h:6379/0", "TWEEN_HEARTBEAT_INTERVAL": 30},
         "heartbeat_interval (30 s) must be at most a third of visibility_timeout (60 s)"),
    ],
)  # fmt: skip
def test_render_and_heartbeat_settings_are_checked(env, line):
    from workers.settings import FarmConfigError

    with pytest.raises(FarmConfigError) as e:
        _settings(**env)
    assert line in str(e.value) and "\n" not in str(e.value)


def test_the_render_message_carries_limits_sized_by_its_work(tmp_path):
    from workers import jobs

    shot = copy_shot(example_shot(), tmp_path, "sized")
    opts = jobs.make_opts(takes=3, out_dir=str(tmp_path / "out"))
    assert jobs._review_frames(str(shot)) == 97
    job = {"id": "j", "takes": 3, "render": True, "work_dir": str(tmp_path / "w")}
    job["limits"] = {"review": [170, 190]}
    sigs = {}

    def walk(sig):  # the canvas nests the stages (a chain holding a chord holding a chain)
        if isinstance(sig, list | tuple):
            for t in sig:
                walk(t)
            return
        if isinstance(sig, dict):
            from celery import signature

            sig = signature(sig)
        if sig.task in ("celery.chain", "celery.group"):
            for t in sig.tasks:
                walk(t)
        elif sig.task == "celery.chord":
            walk(sig.tasks)
            walk(sig.body)
        else:
            sigs[sig.task] = sig

    walk(jobs.build(str(shot), opts, job, "q"))
    review = sigs["tween.render_review"]
    assert (review.options["soft_time_limit"], review.options["time_limit"]) == (170, 190)
    for name in ("tween.validate", "tween.fill_take", "tween.write_layer"):  # the fill's: the worker's own
        assert "time_limit" not in sigs[name].options


def test_embedded_render_past_its_soft_limit_says_so_and_leaves_nothing(tmp_path):
    """A render slowed to about 5 s against a soft limit of 2 s (1 s + 10 ms × 97 frames)."""
    env = embedded_env(tmp_path, slow=("farm_slowrender",), TWEEN_TEST_FRAME_DELAY=0.1,
                       TWEEN_RENDER_SOFT_TIME_LIMIT=1, TWEEN_RENDER_TIME_LIMIT=60, TWEEN_RENDER_FRAME_MS=10)  # fmt: skip
    shots = tmp_path / "shots"
    shot = copy_shot(example_shot(), shots, "slow")
    cmd = [sys.executable, "-m", "pipeline.cli", "fill", str(shot), "--render", "--no-progress"]
    res = subprocess.run(cmd, env=env, cwd=tmp_path, capture_output=True, text=True, timeout=180)
    assert res.returncode == 2, res.stderr[-3000:]
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("tween: error:")]
    # TWEEN_FARM_CONFIG=/dev/null: no file to edit, so only the variables are named
    assert errors == [
        f"tween: error: review render of {shot} hit the farm's soft time limit of 2 s (render_soft_time_limit = "
        "1 s + render_frame_ms = 10 ms × 97 frames × 1 take(s)); raise render_frame_ms or render_soft_time_limit "
        "with TWEEN_RENDER_FRAME_MS / TWEEN_RENDER_SOFT_TIME_LIMIT where the job is submitted"
    ]
    assert res.stdout == ""
    # No version, no media, no scratch, no work folder: only the shot.
    assert sorted(p.name for p in shots.iterdir()) == ["slow.usda"]
    assert "Soft time limit (2s) exceeded" in worker_log(tmp_path)


# --- the hard limit, on a real Redis worker ----------------------------------------------


@pytest.fixture(scope="module")
def farm(tmp_path_factory):
    server = start_redis()
    root = tmp_path_factory.mktemp("shots")
    logs = tmp_path_factory.mktemp("logs")
    env = farm_env(server, [str(root)], TWEEN_VISIBILITY_TIMEOUT=16, TWEEN_RESTORE_INTERVAL=2,
                   TWEEN_FILL_TIME_LIMIT=14, TWEEN_FILL_SOFT_TIME_LIMIT=12)  # fmt: skip
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), str(REPO / "tests")])
    from workers.app import app

    old = app.conf.tween
    try:
        yield SimpleNamespace(server=server, root=root, env=env, logs=logs, app=app)
    finally:
        configure_app(app, old)
        server.cleanup()


def test_render_killed_at_its_hard_limit_is_undone(farm, tmp_path):
    """The render ignores its soft limit (as a render stuck in a GL call would): the worker's
    pool process is killed at the hard limit, and its main process undoes the job."""
    from workers import jobs
    from workers.settings import load_settings

    # The client's settings size the render's limits: soft 2 s + 97 ms, hard 4 s + 97 ms.
    limits = dict(TWEEN_RENDER_SOFT_TIME_LIMIT="2", TWEEN_RENDER_TIME_LIMIT="4", TWEEN_RENDER_FRAME_MS="1")
    configure_app(farm.app, load_settings({**os.environ, **farm.env, **limits}))
    markers = tmp_path / "markers"
    markers.mkdir()
    pool = WorkerPool(farm.env, farm.logs)
    try:
        w = pool.start(concurrency=1, include=["farm_slowrender"], TWEEN_TEST_MARKERS=markers,
                       TWEEN_TEST_FRAME_DELAY=0.2, TWEEN_TEST_IGNORE_SOFT=1)  # fmt: skip
        pool.wait_ready()
        folder = farm.root / "hard"
        shot = copy_shot(example_shot(), folder, "hard")
        (job,) = jobs.submit([str(shot)], jobs.make_opts(takes=1, out_dir=str(folder / "out")), render=True)
        (s,) = jobs.wait([job], progress=False, timeout=120)
        assert s.state == "FAILURE" and s.stage == "review"
        assert s.error.startswith(f"review render of {shot} hit the farm's hard time limit of 5 s")
        assert "TWEEN_RENDER_TIME_LIMIT" in s.error
        assert any(markers.iterdir())  # it was rendering: scratch and frames existed
        t0 = time.monotonic()
        while "Hard time limit" not in w.log_text() and time.monotonic() - t0 < 10:
            time.sleep(0.1)
        assert "Hard time limit (5s) exceeded" in w.log_text()
        # The worker's main process undoes the job once the killed process is gone.
        while (folder / "out").exists() and time.monotonic() - t0 < 15:
            time.sleep(0.1)
        assert not (folder / "out").exists(), sorted(str(p) for p in (folder / "out").rglob("*"))
        assert leftovers(folder) == []
    finally:
        pool.stop_all()
