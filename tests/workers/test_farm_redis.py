"""The farm on a real Redis with real ``tween worker`` processes: batches, bad shots,
refused paths, duplicate delivery, and a host killed in the middle of a fill."""

from __future__ import annotations

import os
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
from redis_server import (
    REPO,
    WorkerPool,
    assert_same_samples,
    configure_app,
    copy_shot,
    example_shot,
    farm_env,
    layer_samples,
    leftovers,
    start_redis,
)

# Test-sized takeover timings (production defaults: 60 s / 5 s / 50 s, see docs/farm.md). The
# fault test's fill is FILL_DELAY plus a cold worker's real fill (model load, trust probes):
# 3-5 s on a slow shared core, so the soft limit leaves it that much room.
VT, RESTORE, HARD, SOFT = 16, 2, 14, 12
FILL_DELAY = 5  # seconds the fault test's fill takes


def _bad_shot(folder: Path, name: str) -> Path:
    """A valid USD file with no skeleton or animation in it."""
    from pxr import Sdf

    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.usda"
    layer = Sdf.Layer.CreateNew(str(path))
    Sdf.CreatePrimInLayer(layer, "/World").specifier = Sdf.SpecifierDef
    layer.Save()
    return path


@pytest.fixture(scope="module")
def farm(tmp_path_factory):
    server = start_redis()
    root = tmp_path_factory.mktemp("shots")
    logs = tmp_path_factory.mktemp("logs")
    env = farm_env(
        server,
        [str(root)],
        TWEEN_VISIBILITY_TIMEOUT=VT,
        TWEEN_RESTORE_INTERVAL=RESTORE,
        TWEEN_FILL_TIME_LIMIT=HARD,
        TWEEN_FILL_SOFT_TIME_LIMIT=SOFT,
    )
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), str(REPO / "tests")])
    from workers.app import app
    from workers.settings import load_settings

    old = app.conf.tween
    # configure_app, not configure: a module run earlier in this process (pytest-xdist's
    # loadfile runs several) may have cached a result backend on another key prefix.
    configure_app(app, load_settings({**os.environ, **env}))
    pool = WorkerPool(env, logs)
    try:
        pool.start(concurrency=1)
        pool.start(concurrency=1)
        pool.wait_ready()
        from pipeline.fill.api import FillOptions, fill_shot

        ref_dir = tmp_path_factory.mktemp("reference")
        ref_shot = copy_shot(example_shot(), ref_dir, "ref")
        ref = fill_shot(str(ref_shot), FillOptions(takes=2, seed=7, out_dir=str(ref_dir)), job_id="reference")
        yield SimpleNamespace(
            server=server, root=root, env=env, pool=pool, logs=logs, ref=layer_samples(ref["layer"]), app=app
        )
    finally:
        pool.stop_all()
        configure_app(app, old)
        server.cleanup()


def _submit(shots, out_dir, **kw):
    from workers import jobs

    opts = jobs.make_opts(takes=2, seed=7, out_dir=str(out_dir))
    return jobs.submit([str(s) for s in shots], opts, **kw)


def _wait(ids, timeout=120):
    from workers import jobs

    return jobs.wait(ids, progress=False, timeout=timeout)


def test_twenty_shots_at_once(farm):
    folder = farm.root / "batch20"
    shots = [copy_shot(example_shot(), folder, f"sh{i:03d}") for i in range(20)]
    t0 = time.monotonic()
    states = _wait(_submit(shots, folder / "out"))
    assert [s.state for s in states] == ["SUCCESS"] * 20, [s.error for s in states]
    for s in states:
        assert Path(s.result["layer"]).parent == folder / "out"
        assert_same_samples(layer_samples(s.result["layer"]), farm.ref)
    assert leftovers(folder) == []
    print(f"20 shots × 2 takes on 2 workers: {time.monotonic() - t0:.1f} s")


def test_bad_shot_fails_alone_without_retry(farm):
    folder = farm.root / "mixed"
    shots = [
        copy_shot(example_shot(), folder, "good1"),
        _bad_shot(folder, "bad"),
        copy_shot(example_shot(), folder, "good2"),
    ]
    states = _wait(_submit(shots, folder / "out"))
    assert [s.state for s in states] == ["SUCCESS", "FAILURE", "SUCCESS"]
    bad = states[1]
    assert bad.stage == "validate"
    assert str(shots[1]) in bad.error and "Error" not in bad.error.split(":")[0]
    meta = farm.app.backend.get_task_meta(f"{bad.id}.validate")
    assert meta["status"] == "FAILURE" and not meta.get("retries")
    assert leftovers(folder) == []
    # The CLI reports it the same way, with a non-zero exit.
    from typer.testing import CliRunner

    from pipeline.cli import app as cli

    res = CliRunner().invoke(cli, ["status", states[0].id, bad.id])
    assert res.exit_code == 2
    assert "success" in res.stdout and bad.error in res.stdout


def test_paths_outside_roots_are_refused(farm, tmp_path):
    from workers.paths import PathRefused

    outside = copy_shot(example_shot(), tmp_path, "outside")
    with pytest.raises(PathRefused, match="outside the shot roots"):
        _submit([outside], farm.root / "out")
    # A symlink inside the root that points out of it.
    link = farm.root / "escape.usda"
    link.symlink_to(outside)
    with pytest.raises(PathRefused, match="outside the shot roots"):
        _submit([link], farm.root / "out")
    inside = copy_shot(example_shot(), farm.root / "esc", "sh")
    with pytest.raises(PathRefused):
        _submit([inside], farm.root / "esc" / ".." / ".." / "elsewhere")
    # The worker checks again against its own roots, whatever the client was told.
    (state,) = _wait(_submit([outside], tmp_path / "out", roots=[str(tmp_path)]), timeout=60)
    assert state.state == "FAILURE" and state.stage == "validate"
    assert "outside the shot roots" in state.error
    assert not (tmp_path / "out").exists()


def test_duplicate_delivery_leaves_one_layer(farm):
    from workers import jobs

    folder = farm.root / "dup"
    shot = copy_shot(example_shot(), folder, "dup")
    (first,) = _wait(_submit([shot], folder / "out"))
    assert first.state == "SUCCESS"
    layers_before = sorted(p.name for p in (folder / "out").iterdir())
    # Deliver the whole job again, same ids and work folder, as a broker would after a lost ack.
    rec = farm.app.backend.get_task_meta(first.id)["result"]
    opts = jobs.make_opts(takes=2, seed=7, out_dir=str(folder / "out"))
    job = {"id": first.id, "takes": rec["takes"], "render": False}
    job["work_dir"] = jobs.work_dir_for(str(shot), opts, first.id)
    for _, tid in jobs.stage_ids(first.id, rec["takes"]):
        farm.app.backend.forget(tid)
    jobs.build(str(shot), opts, job, farm.env["TWEEN_QUEUE"]).apply_async()
    (again,) = _wait([first.id])
    assert again.state == "SUCCESS"
    assert sorted(p.name for p in (folder / "out").iterdir()) == layers_before
    assert again.result["layer"] == first.result["layer"]
    assert_same_samples(layer_samples(again.result["layer"]), farm.ref)
    assert leftovers(folder) == []


def test_host_killed_mid_fill_is_taken_over(farm, tmp_path):
    """SIGKILL a whole worker while it fills; the other finishes within VT + restore + fill."""
    markers = tmp_path / "markers"
    markers.mkdir()
    queue = farm.env["TWEEN_QUEUE"] + ".fault"
    slow = dict(TWEEN_QUEUE=queue, TWEEN_TEST_MARKERS=str(markers), TWEEN_TEST_FILL_DELAY=FILL_DELAY)
    pool = WorkerPool(farm.env, farm.logs)
    try:
        a = pool.start(concurrency=1, include=["farm_slowfill"], **slow)
        b = pool.start(concurrency=1, include=["farm_slowfill"], **slow)
        pool.wait_ready()
        folder = farm.root / "fault"
        shot = copy_shot(example_shot(), folder, "fault")
        from workers import jobs

        opts = jobs.make_opts(takes=1, seed=7, out_dir=str(folder / "out"))
        (job_id,) = jobs.submit([str(shot)], opts, queue=queue)
        t0 = time.monotonic()
        while not any(markers.iterdir()):
            assert time.monotonic() - t0 < 30, "no worker started the fill"
            time.sleep(0.05)
        (marker,) = list(markers.iterdir())
        victim = {w.pgid: w for w in (a, b)}[int(marker.name.split(".")[0])]
        survivor = b if victim is a else a
        time.sleep(1.0)  # well inside the fill
        victim.kill_host()
        t_kill = time.monotonic()
        assert victim.proc.poll() is not None
        budget = VT + RESTORE + FILL_DELAY + 10
        (state,) = _wait([job_id], timeout=budget + 30)
        took = time.monotonic() - t_kill
        assert state.state == "SUCCESS", state.error
        assert took <= budget, f"takeover took {took:.1f} s (budget {budget} s)"
        print(f"host killed; job finished {took:.1f} s later (VT {VT} s, restore every {RESTORE} s)")
        assert f"{job_id}.take0] succeeded" in survivor.log_text()
        written = {Path(state.result["layer"]).name, Path(state.result["review"]).name}
        assert {p.name for p in (folder / "out").iterdir()} == written
        samples = layer_samples(state.result["layer"])
        direct_dir = tmp_path / "direct"
        from pipeline.fill.api import FillOptions, fill_shot

        direct = fill_shot(
            str(copy_shot(shot, direct_dir, "fault")), FillOptions(takes=1, seed=7, out_dir=str(direct_dir))
        )
        assert_same_samples(samples, layer_samples(direct["layer"]))
        assert leftovers(folder) == []
    finally:
        pool.stop_all()
