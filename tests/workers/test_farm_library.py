"""`tween submit-library`: a library built on the farm's training queue by a real
`tween worker --train` process against Redis, its paths checked against the shot roots."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
import uuid

import pytest
from redis_server import REPO, farm_env, start_redis

from pipeline.library.store import open_library

TAKES = ("dataset-2_walk_active_001.bvh.gz", "dataset-2_run_active_001.bvh.gz")


@pytest.fixture(scope="module")
def libfarm(tmp_path_factory, data_dir):
    server = start_redis()
    root = tmp_path_factory.mktemp("libroot")
    logs = tmp_path_factory.mktemp("liblogs")
    takes = root / "takes"
    takes.mkdir()
    for name in TAKES:
        shutil.copy(data_dir / "bandai_namco" / "dataset-2" / name, takes / name)
    env = farm_env(server, [str(root)], TWEEN_TRAIN_QUEUE=f"{server.prefix}train")
    env["PYTHONPATH"] = str(REPO)
    log = logs / "train-worker.log"
    cmd = [
        sys.executable,
        "-m",
        "pipeline.cli",
        "worker",
        "--train",
        "-c",
        "1",
        "-n",
        f"lib-{uuid.uuid4().hex[:6]}@%h",
    ]
    cmd += ["--logfile", str(log), "-l", "info"]
    with open(logs / "train-worker.out", "wb") as out:
        proc = subprocess.Popen(cmd, cwd=REPO, env={**os.environ, **env}, start_new_session=True, stdout=out,
                                stderr=subprocess.STDOUT)  # fmt: skip
    try:
        t0 = time.monotonic()
        while " ready." not in (log.read_text() if log.exists() else ""):
            assert proc.poll() is None, (logs / "train-worker.out").read_text()[-2000:]
            assert time.monotonic() - t0 < 60, "training worker not ready"
            time.sleep(0.1)
        yield root, takes, {**os.environ, **env}
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, 9)
            proc.wait()
        server.cleanup()


def _tween(env, *args):
    return subprocess.run([sys.executable, "-m", "pipeline.cli", *map(str, args)], capture_output=True, text=True,
                          env=env, cwd=REPO, timeout=300)  # fmt: skip


def test_a_library_is_built_on_the_training_queue(libfarm):
    root, takes, env = libfarm
    out = root / "library"
    r = _tween(env, "submit-library", takes, "--out", out, "--licence", "studio", "--wait")
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    lib = open_library(out)
    assert res["takes"] == 2 and res["hash"] == lib.hash and lib.manifest["licence"] == "studio"
    job = r.stderr.strip().splitlines()[0]
    assert job.startswith("lib-")
    s = _tween(env, "status", job)
    assert s.returncode == 0 and f"hash {lib.hash}" in s.stdout and "success, 2 take(s)" in s.stdout


def test_paths_outside_the_shot_roots_are_refused_before_any_job(libfarm, tmp_path):
    root, takes, env = libfarm
    r = _tween(env, "submit-library", takes, "--out", tmp_path / "elsewhere")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "outside the shot roots" in r.stderr
    assert not (tmp_path / "elsewhere").exists()


def test_takes_linked_from_outside_the_shot_roots_are_refused(libfarm, tmp_path):
    """Only the takes folder was checked: a folder linked inside it from elsewhere was read
    (library.json recorded a take outside the roots)."""
    root, takes, env = libfarm
    outside = tmp_path / "outside"
    outside.mkdir()
    shutil.copy(takes / TAKES[0], outside / TAKES[0])
    linked = root / "linked"
    linked.mkdir()
    (linked / "more").symlink_to(outside)
    r = _tween(env, "submit-library", linked, "--out", root / "linkedlib", "--wait")
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert f"take resolves to {outside / TAKES[0]}, outside the shot roots" in r.stderr
    assert not (root / "linkedlib").exists()


def test_a_library_job_that_fails_says_why(libfarm):
    root, takes, env = libfarm
    empty = root / "empty"
    empty.mkdir()
    r = _tween(env, "submit-library", empty, "--out", root / "nolib", "--wait")
    assert r.returncode == 2 and "no BVH or USD takes" in r.stderr.splitlines()[-1]
    bad = root / "bad"  # takes the worker reads and cannot use: its job fails, saying why
    bad.mkdir()
    (bad / "broken.bvh").write_text("HIERARCHY\n")
    r = _tween(env, "submit-library", bad, "--out", root / "badlib", "--wait")
    assert r.returncode == 2 and r.stderr.splitlines()[-1].startswith("tween: error: "), r.stderr
    assert r.stderr.splitlines()[0].startswith("lib-") and not (root / "badlib").exists()


def test_the_build_reports_its_progress_as_task_state(tmp_path, data_dir, monkeypatch):
    """The task body on its own (no broker): each take's progress line becomes a PROGRESS
    state, the last one all takes done; the result is the build's summary."""
    from dataclasses import replace

    from workers.app import app as fill_app
    from workers.train_tasks import library_build

    takes = tmp_path / "takes"
    takes.mkdir()
    for name in TAKES:
        shutil.copy(data_dir / "bandai_namco" / "dataset-2" / name, takes / name)
    monkeypatch.setitem(fill_app.conf, "tween", replace(fill_app.conf.tween, shot_roots=(str(tmp_path),)))
    states = []
    monkeypatch.setattr(library_build, "update_state", lambda state, meta: states.append((state, dict(meta))))
    res = library_build.run(str(takes), str(tmp_path / "lib"), {"licence": "studio"})
    assert res["takes"] == 2 and open_library(tmp_path / "lib").manifest["licence"] == "studio"
    assert states[0][0] == "STARTED"
    progress = [m for s, m in states if s == "PROGRESS"]
    assert progress and progress[-1]["done"] == progress[-1]["total"] == 2
    with pytest.raises(Exception, match="outside the shot roots"):
        library_build.run(str(data_dir), str(tmp_path / "lib2"), {})


def test_a_farm_build_waits_for_another_build_of_its_library_half_its_time_limit(tmp_path, monkeypatch):
    """The farm task ran `tween library build` with its own 300 s lock wait, so a build queued
    behind another build of the same library failed after 5 minutes; it now waits half its
    soft time limit (within 300 s and 24 h), the other half left for its own build."""
    from workers import train_tasks
    from workers.app import app as fill_app
    from workers.app import train_app

    assert train_tasks.farm_lock_wait(None) == 300
    assert train_tasks.farm_lock_wait(100) == 300
    assert train_tasks.farm_lock_wait(12 * 3600 * 0.95) == 12 * 3600 * 0.95 / 2
    assert train_tasks.farm_lock_wait(10**9) == 24 * 3600

    takes = tmp_path / "takes"
    takes.mkdir()
    (takes / "walk.bvh").write_text("HIERARCHY\n")  # listed, never read: the build is not run
    seen = []

    class Stop(Exception):
        pass

    def popen(cmd, **kw):
        seen.append(cmd)
        raise Stop

    monkeypatch.setattr(train_tasks.subprocess, "Popen", popen)
    from dataclasses import replace

    soft, settings = train_app.conf.task_soft_time_limit, fill_app.conf.tween
    train_app.conf.task_soft_time_limit = 41040  # the default 12 h limit's soft one
    fill_app.conf.tween = replace(settings, shot_roots=(str(tmp_path),))
    try:
        with pytest.raises(Stop):
            train_tasks.library_build.run(str(takes), str(tmp_path / "lib"), {})
    finally:
        train_app.conf.task_soft_time_limit, fill_app.conf.tween = soft, settings
    (cmd,) = seen
    assert cmd[cmd.index("--lock-wait") + 1] == "20520", cmd
