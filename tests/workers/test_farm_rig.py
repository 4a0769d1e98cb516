"""Per-rig models on a real farm: `tween train-rig` (tiny schedule) as a task on its own
queue, run by a real `tween worker --train-rig` process against Redis with progress in the
task meta; a fill worker keeps filling meanwhile and then fills a creature shot with the
model it just trained."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import uuid
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from redis_server import REPO, WorkerPool, copy_shot, example_shot, farm_env, leftovers, start_redis
from test_rig_fill import CREATURE_ANIM, creature_shot


@pytest.fixture(scope="module")
def rigfarm(tmp_path_factory):
    server = start_redis()
    root = tmp_path_factory.mktemp("rigshots")
    logs = tmp_path_factory.mktemp("riglogs")
    models = root / "models"
    models.mkdir()
    env = farm_env(
        server,
        [str(root)],
        TWEEN_TRAIN_RIG_QUEUE=f"{server.prefix}train_rig",
        TWEEN_MODELS=str(models),
        TWEEN_VISIBILITY_TIMEOUT=12,
        TWEEN_FILL_TIME_LIMIT=10,
        TWEEN_FILL_SOFT_TIME_LIMIT=8,
    )
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), str(REPO / "tests")])
    from celery import Celery

    from workers.app import configure
    from workers.settings import load_settings

    # Fresh client apps: Celery caches an app's result backend and broker pool, so the
    # module-level apps may still point at another test module's Redis key prefix.
    s = load_settings({**os.environ, **env})
    app = configure(Celery("tween-test-client"), s)
    rig_app = configure(Celery("tween-test-rig-client"), s, rig=True)
    mp = pytest.MonkeyPatch()
    mp.setattr("workers.jobs.app", app)
    mp.setattr("workers.jobs.rig_app", rig_app)
    pool = WorkerPool(env, logs)
    rig_log = logs / "rig-worker.log"
    name = f"rig-{uuid.uuid4().hex[:6]}"
    cmd = [sys.executable, "-m", "pipeline.cli", "worker", "--train-rig", "-c", "1", "-n", f"{name}@%h"]
    cmd += ["--logfile", str(rig_log), "-l", "info"]
    with open(logs / "rig-worker.out", "wb") as out:
        rig = subprocess.Popen(cmd, cwd=REPO, env={**os.environ, **env}, start_new_session=True, stdout=out,
                               stderr=subprocess.STDOUT)  # fmt: skip
    try:
        pool.start(concurrency=1)
        pool.wait_ready()
        t0 = time.monotonic()
        while " ready." not in (rig_log.read_text() if rig_log.exists() else ""):
            assert rig.poll() is None, (logs / "rig-worker.out").read_text()[-2000:]
            assert time.monotonic() - t0 < 60, "rig worker not ready"
            time.sleep(0.1)
        yield SimpleNamespace(server=server, root=root, models=models, env=env, app=app, rig_log=rig_log)
    finally:
        if rig.poll() is None:
            rig.terminate()
            try:
                rig.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(rig.pid, 9)
                rig.wait()
        pool.stop_all()
        mp.undo()
        server.cleanup()


def test_train_rig_on_its_queue_with_progress_then_fill_with_it(rigfarm):
    from pipeline.rig.store import read_rig_json
    from workers import jobs

    clip = creature_shot(rigfarm.root / "clips" / "creature_clip.usda", T=61, keys_every=1)
    out = rigfarm.models / "creature"
    job = jobs.submit_train_rig(str(clip), str(out), {"schedule": "tiny", "seed": 0})
    assert job.startswith("rig-") and jobs.train_rig_state(job).state in ("QUEUED", "RUNNING")
    # A fill submitted after the training finishes first: training has its own queue and worker.
    human = copy_shot(example_shot(), rigfarm.root / "human", "sh010")
    (fill_job,) = jobs.submit([str(human)], jobs.make_opts(out_dir=str(rigfarm.root / "human" / "out")))
    seen, fill_done_while_training = [], False
    t0 = time.monotonic()
    while True:
        st = jobs.train_rig_state(job)
        seen.append((st.state, dict(st.result or {}) if st.state == "RUNNING" else None))
        if not fill_done_while_training and not st.finished:
            fill_done_while_training = jobs.state(fill_job).state == "SUCCESS"
        if st.finished:
            break
        assert time.monotonic() - t0 < 240, f"training not finished: {seen[-1]}"
        time.sleep(0.1)
    took = time.monotonic() - t0
    assert st.state == "SUCCESS", st.error
    info = read_rig_json(out)
    assert st.result["model"] == "creature" and st.result["model_hash"] == info.hash
    assert st.result["out"] == str(out) and st.result["progress_updates"] > 0
    progress = [p for s, p in seen if s == "RUNNING" and p and p.get("levels")]
    assert progress, f"no progress seen in the task meta: {seen[:5]} ... {seen[-5:]}"
    assert all(0 <= p["fraction"] <= 1 and p["iterations"] > 0 for p in progress)
    assert [p["fraction"] for p in progress] == sorted(p["fraction"] for p in progress)
    assert fill_done_while_training, "the fill waited for the training"
    # The worker logs "succeeded" just after it stores the result: give its log a moment.
    t_log = time.monotonic()
    while f"{job}] succeeded" not in rigfarm.rig_log.read_text() and time.monotonic() - t_log < 15:
        time.sleep(0.2)
    assert f"{job}] succeeded" in rigfarm.rig_log.read_text()
    print(f"tiny train-rig on the farm: {took:.1f} s, {len(progress)} progress polls")
    # `tween status` knows training jobs.
    from typer.testing import CliRunner

    from pipeline.cli import app as cli

    res = CliRunner().invoke(cli, ["status", job])
    assert res.exit_code == 0 and f"success, model {out} (creature, hash {info.hash})" in res.stdout

    # The fill farm picks the new model for the creature automatically (TWEEN_MODELS on the worker).
    shot = creature_shot(rigfarm.root / "shots" / "cr200.usda", T=61, keys_every=12)
    (fid,) = jobs.submit([str(shot)], jobs.make_opts(takes=2, out_dir=str(rigfarm.root / "shots" / "out")))
    (fs,) = jobs.wait([fid], progress=False, timeout=120)
    assert fs.state == "SUCCESS", fs.error
    assert fs.result["models"] == {CREATURE_ANIM: "creature"} and fs.result["model_hash"] == info.hash
    from pxr import Usd

    src_stage, stage = Usd.Stage.Open(str(shot)), Usd.Stage.Open(fs.result["review"])
    src, filled = src_stage.GetPrimAtPath(CREATURE_ANIM), stage.GetPrimAtPath(CREATURE_ANIM + "_tween")
    for t in src.GetAttribute("rotations").GetTimeSamples():
        assert np.array_equal(
            np.array(src.GetAttribute("rotations").Get(t)), np.array(filled.GetAttribute("rotations").Get(t))
        )
    assert leftovers(rigfarm.root / "shots") == []


def test_bad_training_jobs_fail_with_one_line(rigfarm, tmp_path):
    from workers import jobs
    from workers.paths import PathRefused

    with pytest.raises(PathRefused, match="outside the shot roots"):
        jobs.submit_train_rig(str(tmp_path / "clip.usda"), str(rigfarm.models / "x"), {"schedule": "tiny"})
    from workers.errors import JobError

    with pytest.raises(JobError, match="unknown train-rig option"):
        jobs.submit_train_rig(str(rigfarm.root / "c.usda"), str(rigfarm.models / "x"), {"shell": "yes"})
    missing = rigfarm.root / "clips" / "missing.usda"
    job = jobs.submit_train_rig(str(missing), str(rigfarm.models / "missing"), {"schedule": "tiny"})
    st = jobs.wait_train_rig(job, progress=False, poll=0.2, timeout=120)
    assert st.state == "FAILURE" and str(missing) in st.error and "file not found" in st.error
    assert "\n" not in st.error
    assert not (rigfarm.models / "missing" / "rig.json").exists()
    assert jobs.train_rig_state("rig-nope").state == "UNKNOWN"


def test_submit_train_rig_cli_needs_a_broker(tmp_path):
    env = {**os.environ, "TWEEN_FARM_CONFIG": os.devnull, "TWEEN_CACHE": str(tmp_path)}
    env.pop("TWEEN_BROKER_URL", None)
    clip = creature_shot(tmp_path / "c.usda", T=31)
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "submit-train-rig", str(clip), "--out", str(tmp_path / "m")],
                       capture_output=True, text=True, env=env, cwd=REPO)  # fmt: skip
    assert r.returncode == 2 and "no broker configured" in r.stderr and r.stdout == ""
    assert not Path(tmp_path / "m").exists()
