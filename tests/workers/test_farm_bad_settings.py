"""Farm settings and job inputs that were internal errors, jobs sent to fail on a worker, or a
worker trusting what its chord handed it: each is one line, exit 2, before anything runs."""

from __future__ import annotations

import gzip
import os
import re
import shutil
import subprocess
import sys
import time
import uuid
from contextlib import nullcontext
from dataclasses import replace
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
NOWHERE = "redis://127.0.0.1:1/0"  # a port nothing listens on
BAD_BACKENDS = {
    "garbage": "not a result backend Celery knows",
    "db+sqlite:////nonexistent/x.db": "cannot connect",
    "db+postgresql://127.0.0.1:1/x": "TWEEN_RESULT_BACKEND=db+postgresql://127.0.0.1:1/x",
    "mongodb://127.0.0.1:1/x": "TWEEN_RESULT_BACKEND=mongodb://127.0.0.1:1/x",
}


def _tween(tmp_path: Path, *args: str, timeout: float = 60, **env_kw: str):
    env = {k: v for k, v in os.environ.items() if not k.startswith("TWEEN_")}
    env.update(
        TWEEN_FARM_CONFIG=os.devnull, TWEEN_CACHE=str(tmp_path / "cache"), TWEEN_SHOT_ROOTS=str(tmp_path)
    )
    env.update(TWEEN_BROKER_URL="redis://127.0.0.1:6379/13", TWEEN_KEY_PREFIX=f"tw-{uuid.uuid4().hex[:8]}:")
    env.update(env_kw)
    cmd = [sys.executable, "-m", "pipeline.cli", *map(str, args)]
    return subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=timeout)


def _refused(res, *says: str) -> str:
    assert res.returncode == 2 and res.stdout == "", res.stderr[-3000:]
    assert res.stderr.count("\n") == 1 and res.stderr.startswith("tween: error: "), res.stderr[-3000:]
    for s in says:
        assert s in res.stderr, res.stderr
    return res.stderr


@pytest.fixture
def shot(tmp_path) -> Path:
    p = tmp_path / "sh010.usda"
    shutil.copy(REPO / "examples" / "sh010_walk.usda", p)
    return p


@pytest.mark.parametrize("backend", ["garbage", "db+sqlite:////nonexistent/x.db"])
def test_a_worker_with_a_bad_result_backend_never_starts(tmp_path, backend):
    """It exited 0 after Celery's CRITICAL "Unrecoverable error" and hundreds of lines."""
    err = _refused(_tween(tmp_path, "worker", "-c", "1", TWEEN_RESULT_BACKEND=backend), BAD_BACKENDS[backend])
    assert "TWEEN_RESULT_BACKEND" in err


def test_the_config_files_result_backend_is_named(tmp_path):
    cfg = tmp_path / "farm.toml"
    cfg.write_text('broker_url = "redis://127.0.0.1:6379/13"\nresult_backend = "garbage"\n')
    env = {"TWEEN_FARM_CONFIG": str(cfg), "TWEEN_BROKER_URL": ""}
    _refused(_tween(tmp_path, "worker", "-c", "1", **env), f"{cfg}: result_backend: not a result backend")


@pytest.mark.parametrize("backend", sorted(BAD_BACKENDS))
def test_status_with_a_bad_result_backend_is_one_line(tmp_path, backend):
    """ModuleNotFoundError, OperationalError after 10 s, ImproperlyConfigured: internal errors."""
    t0 = time.monotonic()
    _refused(_tween(tmp_path, "status", "abc", TWEEN_RESULT_BACKEND=backend), BAD_BACKENDS[backend])
    assert time.monotonic() - t0 < 9


@pytest.mark.parametrize("cmd", ["submit", "fill"])
@pytest.mark.parametrize("backend", ["garbage", "db+sqlite:////nonexistent/x.db"])
def test_submit_and_fill_with_a_bad_result_backend_send_nothing(tmp_path, shot, cmd, backend):
    _refused(_tween(tmp_path, cmd, shot.name, TWEEN_RESULT_BACKEND=backend), BAD_BACKENDS[backend])
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "cache") == [shot.name]


def test_an_unreachable_redis_backend_still_says_cannot_connect(tmp_path):
    _refused(
        _tween(tmp_path, "status", "abc", TWEEN_RESULT_BACKEND=NOWHERE),
        f"result backend {NOWHERE}: cannot connect",
    )


def test_a_database_server_that_does_not_answer_cannot_connect():
    """Its driver is not installed here: the reachability check itself, and its one line."""
    from celery import Celery

    from workers.app import check_backend
    from workers.backends import problem, reach
    from workers.errors import FarmConnectionError

    with pytest.raises(OSError):
        reach("db+postgresql://u:pw@127.0.0.1:1/x", 1.0)
    app = Celery("t", set_as_current=False)
    app.conf.result_backend = "db+mysql://u:secretpw@127.0.0.1:1/x"
    with pytest.raises(
        FarmConnectionError, match="result backend db.mysql://u:\\*\\*\\*@127.0.0.1:1/x: cannot connect"
    ):
        check_backend(app, 1.0)
    assert problem("redis://127.0.0.1:1/0") is None and problem("db+sqlite:///:memory:") is None
    assert "Celery knows" in problem("garbage") and "driver" in problem("db+postgresql://h/x")


def test_bench_farm_checks_the_broker_before_any_fill(tmp_path):
    """It ran ~9 s of direct fills, then an internal ConnectionError, leaving its work folder."""
    t0 = time.monotonic()
    res = _tween(
        tmp_path, "bench-farm", "--shots", "1", "--out", tmp_path / "b.json", TWEEN_BROKER_URL=NOWHERE
    )
    _refused(res, f"broker {NOWHERE}: cannot connect")
    assert time.monotonic() - t0 < 8
    assert not (tmp_path / "cache" / "bench-farm").exists() and not (tmp_path / "b.json").exists()
    _refused(
        _tween(tmp_path, "bench-farm", "--shots", "1", TWEEN_RESULT_BACKEND="garbage"), "TWEEN_RESULT_BACKEND"
    )


@pytest.mark.parametrize(
    "args, says",
    [
        (["", "--out", "lib/out"], "takes folder '': empty"),
        (["takes", "--out", ""], "--out '': empty"),
        (["takes", "--include", "", "--out", "lib/out"], "--include '': names no file-name glob"),
        (["takes", "--include", " , ", "--out", "lib/out"], "--include ' , ': names no file-name glob"),
    ],
)
def test_submit_library_refuses_empty_paths_and_globs(tmp_path, args, says):
    """'' was the working folder (its takes sent as a job); --include '' every take."""
    (tmp_path / "takes").mkdir()
    (tmp_path / "takes" / "a.bvh").write_text("HIERARCHY\n")
    _refused(_tween(tmp_path, "submit-library", *args, TWEEN_BROKER_URL=NOWHERE), says)
    assert not (tmp_path / "lib").exists()


def test_blank_shot_roots_are_refused(tmp_path):
    """' ' was taken for a root (the file refuses shot_roots = [""])."""
    from workers.settings import FarmConfigError, load_settings

    for roots in (" ", f"{tmp_path}{os.pathsep} ", f"{tmp_path}{os.pathsep}"):
        env = {"TWEEN_FARM_CONFIG": os.devnull, "TWEEN_BROKER_URL": "redis://h", "TWEEN_SHOT_ROOTS": roots}
        with pytest.raises(FarmConfigError, match="TWEEN_SHOT_ROOTS=.*an empty folder path"):
            load_settings(env)
    _refused(
        _tween(tmp_path, "status", "abc", TWEEN_SHOT_ROOTS=" "), "TWEEN_SHOT_ROOTS=' ': an empty folder path"
    )


@pytest.mark.parametrize("kind", ["library", "rig"])
def test_a_failed_long_job_keeps_its_source(kind, tmp_path):
    """`tween status` of a failed library or rig job showed an empty path ("shot": "")."""
    from celery import Celery
    from celery.utils.objects import Bunch
    from redis_server import farm_env, start_redis

    from workers import jobs
    from workers.app import configure
    from workers.errors import JobError
    from workers.settings import load_settings

    server = start_redis()
    try:
        s = load_settings(farm_env(server, [str(tmp_path)]))
        app = configure(Celery("t", set_as_current=False), s, train=kind == "library", rig=kind == "rig")
        job_id = f"{'lib' if kind == 'library' else 'rig'}-{uuid.uuid4().hex}"
        source = str(tmp_path / "takes")
        app.backend.store_result(job_id, {"source": source, "out": "x"}, jobs.SUBMITTED)
        assert jobs._long_job_state(app, job_id, "build", "job").shot == source
        req = Bunch(task="tween.x", args=[source, str(tmp_path / "out"), {}], kwargs={}, hostname="w", retries=0,
                    delivery_info={}, group=None, parent_id=None, id=job_id, chord=None, ignore_result=False)  # fmt: skip
        app.backend.store_result(job_id, JobError("the takes could not be read"), "FAILURE", request=req)
        js = jobs._long_job_state(app, job_id, "build", "job")
        assert js.state == "FAILURE" and js.shot == source and js.as_dict()["shot"] == source
    finally:
        server.cleanup()


@pytest.fixture(scope="module")
def bvh_clip(tmp_path_factory, data_dir) -> Path:
    folder = tmp_path_factory.mktemp("rigclip")
    src = data_dir / "bandai_namco" / "dataset-2" / "dataset-2_walk_active_001.bvh.gz"
    out = folder / "walk.bvh"
    out.write_bytes(gzip.decompress(src.read_bytes()))
    return out


@pytest.mark.parametrize(
    "args, says",
    [
        (["--frames", "10:5"], "frames 10:5 are not inside"),
        (["--frames", ""], "--frames '': empty"),
        (["--skeleton", ""], "--skeleton '': empty"),
        (["--skeleton", "/Nope"], "--skeleton applies to USD shots"),
        (["--contacts", "Nope"], "--contacts: no joint named 'Nope'"),
        (["--name", "a/b"], "--name 'a/b': a model name, not a path"),
        (["--name", ""], "--name '': empty"),
        (["--licence", ""], "--licence '': empty"),
        (["--licence", "a\nb"], "--licence 'a\\nb': must be one line"),
        (["--credit", ""], "--credit '': empty"),
        (["--out", ""], "--out '': empty"),
    ],
)
def test_submit_train_rig_runs_train_rigs_checks_before_sending(tmp_path, bvh_clip, args, says):
    """Each exited 0 with a job id, whose job failed on the worker (or trained the default)."""
    clip = tmp_path / bvh_clip.name
    shutil.copy(bvh_clip, clip)
    argv = ["submit-train-rig", clip.name, "--schedule", "tiny"]
    argv += [] if "--out" in args else ["--out", "rig/x"]
    _refused(_tween(tmp_path, *argv, *args, TWEEN_BROKER_URL=NOWHERE), says)
    assert not (tmp_path / "rig").exists()


def test_submit_train_rig_refuses_a_source_that_is_no_clip(tmp_path):
    (tmp_path / "clip.txt").write_text("not a clip\n")
    res = _tween(tmp_path, "submit-train-rig", "clip.txt", "--out", "rig/x", TWEEN_BROKER_URL=NOWHERE)
    _refused(res, "clip.txt: not a USD shot")


def _review_job(tmp_path, monkeypatch, render: bool):
    from workers import tasks

    root = tmp_path / "show"
    root.mkdir()
    shot = root / "sh010.usda"
    shot.write_text("#usda 1.0\n")
    monkeypatch.setitem(tasks.app.conf, "tween", replace(tasks.app.conf.tween, shot_roots=(str(root),)))
    monkeypatch.setattr(tasks, "_stage", lambda *a: nullcontext())
    job = {"id": "j1", "work_dir": str(root / ".tween-work" / "j1"), "render": render, "takes": 1}
    layer = {"layer": str(root / "sh010.tween.v001.usda"), "review": str(root / "sh010.review.v001.usda")}
    return tasks, str(shot), job, layer


@pytest.mark.parametrize("render", [True, False])
def test_the_review_stage_trusts_no_forged_layer(tmp_path, monkeypatch, render):
    """A forged takes=10**9 made a worker allocate 11 GB; paths outside the roots were opened."""
    from workers.errors import JobError

    tasks, shot, job, layer = _review_job(tmp_path, monkeypatch, render)
    for forged, says in (
        ({"takes": 10**9}, "handed 1000000000 takes; a fill makes 1 to 64"),
        ({"takes": "3"}, "handed '3' takes"),
        ({"review": "/etc/passwd"}, "review layer resolves to /etc/passwd, outside the shot roots"),
        ({"layer": str(tmp_path / "elsewhere.usda")}, "outside the shot roots"),
        ({"layer": ["x"]}, "a layer path that is no path"),
    ):
        with pytest.raises(JobError, match=re.escape(says)):
            tasks.render_review.run({**layer, "takes": 2, **forged}, shot, {}, job)
    with pytest.raises(JobError, match="outside the shot roots"):  # the job's own paths too
        tasks.render_review.run(dict(layer, takes=2), shot, {}, dict(job, work_dir="/tmp/elsewhere"))
