"""The embedded default: `tween fill` with no broker configured goes through Celery on a
local SQLite broker and worker, and never opens a network connection."""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest
from cli_timing import cli_floor
from redis_server import REPO, copy_shot, example_shot, layer_samples

# Loaded into every Python process of the run (CLI, worker, pool children): records and
# refuses any connection to a network address, so "no broker contacted" is checked, not assumed.
GUARD = """
import os, socket, sys
_LOG = os.environ["TWEEN_TEST_NET_LOG"]
def _hook(event, args):
    if event == "socket.connect" and args[0].family in (socket.AF_INET, socket.AF_INET6):
        with open(_LOG, "a") as f:
            f.write(f"{os.getpid()} {args[1]!r}\\n")
        raise ConnectionRefusedError(f"test guard: network connection to {args[1]!r} refused")
sys.addaudithook(_hook)
"""


def _env(tmp_path: Path) -> dict:
    guard_dir = tmp_path / "guard"
    guard_dir.mkdir()
    (guard_dir / "sitecustomize.py").write_text(GUARD)
    env = {k: v for k, v in os.environ.items() if not k.startswith("TWEEN_")}
    env.update(
        TWEEN_CACHE=str(tmp_path / "cache"),
        TWEEN_FARM_CONFIG=os.devnull,
        TWEEN_TEST_NET_LOG=str(tmp_path / "net.log"),
        PYTHONPATH=os.pathsep.join([str(guard_dir), str(REPO)]),
    )
    if "TWEEN_DATA" in os.environ:
        env["TWEEN_DATA"] = os.environ["TWEEN_DATA"]
    return env


def test_guard_catches_connections(tmp_path):
    env = _env(tmp_path)
    code = "import socket\ntry: socket.create_connection(('127.0.0.1', 6379), timeout=1)\nexcept OSError as e: print(e)"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert "test guard" in out.stdout
    assert "6379" in (tmp_path / "net.log").read_text()


def test_embedded_fill_without_any_broker(tmp_path):
    env = _env(tmp_path)
    shot = copy_shot(example_shot(), tmp_path / "shots", "demo")
    before = shot.read_bytes()
    cmd = [
        sys.executable,
        "-m",
        "pipeline.cli",
        "fill",
        str(shot),
        "--takes",
        "2",
        "--seed",
        "3",
        "--no-progress",
    ]
    res = subprocess.run(cmd, env=env, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-3000:]
    assert not (tmp_path / "net.log").exists(), (tmp_path / "net.log").read_text()
    layer = Path(res.stdout.split("layer ", 1)[1].split(",")[0].strip())
    assert layer.parent == shot.parent and layer.is_file()
    assert shot.read_bytes() == before  # the user's shot is never modified
    # The same values as filling in process.
    from pipeline.fill.api import FillOptions, fill_shot

    direct = fill_shot(str(copy_shot(shot, tmp_path / "direct", "demo")), FillOptions(takes=2, seed=3))
    samples = layer_samples(layer)
    ref = layer_samples(direct["layer"])
    assert sorted(samples) == sorted(ref) and samples
    # It went through Celery: the worker ran each stage and stored results in SQLite.
    db = tmp_path / "cache" / "farm" / "results.sqlite"
    with sqlite3.connect(db) as con:
        rows = dict(con.execute("select task_id, status from celery_taskmeta"))
    stages = {k.split(".", 1)[1] for k, v in rows.items() if "." in k and v == "SUCCESS"}
    assert stages == {"validate", "take0", "take1", "layer", "review"}
    assert not list(shot.parent.glob(".tween-work"))
    logs = list((tmp_path / "cache" / "farm" / "logs").glob("*.log"))
    assert logs and "tween.fill_take" in logs[0].read_text()


def test_embedded_bad_shot_reports_and_fails(tmp_path):
    env = _env(tmp_path)
    bad = tmp_path / "shots" / "broken.usda"
    bad.parent.mkdir()
    bad.write_text("#usda 1.0\n(\n  this is not usd\n")
    cmd = [sys.executable, "-m", "pipeline.cli", "fill", str(bad), "--no-progress"]
    res = subprocess.run(cmd, env=env, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    lines = [ln for ln in res.stderr.splitlines() if ln.startswith("tween: error:")]
    assert len(lines) == 1 and str(bad) in lines[0], res.stderr[-2000:]
    assert res.stdout == ""
    assert sorted(p.name for p in bad.parent.iterdir()) == ["broken.usda"]
    json.dumps(lines)


def test_embedded_fill_single_take_with_render(tmp_path):
    # `make demo`'s path: one take (no variant set to select) rendered by the farm's last stage.
    env = _env(tmp_path)
    shot = copy_shot(example_shot(), tmp_path / "shots", "demo")
    out = tmp_path / "out"
    cmd = [
        sys.executable,
        "-m",
        "pipeline.cli",
        "fill",
        str(shot),
        "--render",
        "--out-dir",
        str(out),
        "--no-progress",
    ]
    res = subprocess.run(cmd, env=env, cwd=tmp_path, capture_output=True, text=True, timeout=180)
    assert res.returncode == 0, res.stderr[-3000:]
    mp4 = Path(res.stdout.split("render ", 1)[1].split()[0].strip(","))
    assert mp4.suffix == ".mp4" and mp4.stat().st_size > 10_000
    assert len(list(mp4.parent.glob("*.png"))) > 10
    # Every output is said: the contact sheet and the timeline too; and on stderr the job id
    # (what `tween status` takes) and the trusted fill's decision per character.
    sheet = Path(res.stdout.split("contact sheet ", 1)[1].split()[0].strip(","))
    otio = Path(res.stdout.split("timeline ", 1)[1].split()[0].strip(","))
    assert sheet.is_file() and sheet.suffix == ".png" and otio.is_file() and otio.suffix == ".otio"
    job = [ln for ln in res.stderr.splitlines() if ln.startswith(f"tween: {shot}: job ")]
    assert len(job) == 1 and len(job[0].split()[-1]) == 32
    assert any(ln.startswith(f"tween: {shot} ") and ": trust " in ln for ln in res.stderr.splitlines())


def test_identical_takes_are_said_once_and_rendered_once(tmp_path):
    """The trusted fill decided for the spline (here forced): every take is the same fill."""
    env = _env(tmp_path)
    shot = copy_shot(example_shot(), tmp_path / "shots", "same")
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "pipeline.cli", "fill", str(shot), "--takes", "2", "--trust", "spline",
           "--render", "--out-dir", str(out), "--no-progress"]  # fmt: skip
    res = subprocess.run(cmd, env=env, cwd=tmp_path, capture_output=True, text=True, timeout=240)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "take 1 = take 0" in res.stdout and res.stdout.count(".mp4") == 1
    assert any(
        "take 1 = take 0, bit for bit" in ln and "rendered once" in ln for ln in res.stderr.splitlines()
    )
    assert len(list((out / "review").glob("*.mp4"))) == 1


def test_an_experimental_model_is_said_once_and_in_the_farm_result(tmp_path):
    """As fill-local (tests/infer/test_registry.py): one warning line per fill, and the job's
    result (`tween status --json`) says why the model is experimental."""
    from pipeline.infer.folder import experimental

    env = _env(tmp_path)
    shot = copy_shot(example_shot(), tmp_path / "shots", "exp")
    cmd = [sys.executable, "-m", "pipeline.cli", "fill", str(shot), "--model", "cmu-s123", "--no-progress"]
    res = subprocess.run(cmd, env=env, cwd=tmp_path, capture_output=True, text=True, timeout=180)
    assert res.returncode == 0, res.stderr[-3000:]
    why = experimental("cmu-s123")
    warned = [ln for ln in res.stderr.splitlines() if ln.startswith("tween: warning:")]
    assert warned == [f"tween: warning: --model cmu-s123 is experimental ({why}); not for production shots"]
    job = res.stderr.split(": job ", 1)[1].split()[0]
    cmd = [sys.executable, "-m", "pipeline.cli", "status", job, "--json"]
    st = subprocess.run(cmd, env=env, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert st.returncode == 0, st.stderr[-3000:]
    result = json.loads(st.stdout)["result"]
    assert result["model"] == "tween-cmu-s123-delta-ft" and result["experimental"] == why


def test_a_run_leaves_no_queue_or_message_in_the_embedded_broker(tmp_path):
    import sqlite3

    env = _env(tmp_path)
    shot = copy_shot(example_shot(), tmp_path / "shots", "q")
    for n in range(2):
        cmd = [sys.executable, "-m", "pipeline.cli", "fill", str(shot), "--model", "interp", "--out-dir",
               str(tmp_path / f"o{n}"), "--no-progress"]  # fmt: skip
        res = subprocess.run(cmd, env=env, cwd=tmp_path, capture_output=True, text=True, timeout=180)
        assert res.returncode == 0, res.stderr[-3000:]
    db = sqlite3.connect(Path(env["TWEEN_CACHE"]) / "farm" / "broker.sqlite")
    assert db.execute("select name from kombu_queue").fetchall() == []
    assert db.execute("select count(*) from kombu_message").fetchall() == [(0,)]


def test_what_needs_no_farm_is_checked_before_any_farm(tmp_path):
    """A shot without an animation, and (broker down) a path outside the shot roots, are
    answered by the client in one line, before a worker starts or a broker is contacted."""
    import time

    env = _env(tmp_path)
    shots = tmp_path / "shots"
    shots.mkdir()
    noskel = shots / "noskel.usda"
    noskel.write_text('#usda 1.0\ndef Xform "World" {}\n')
    floor = cli_floor(env, tmp_path)
    t0 = time.monotonic()
    res = subprocess.run([sys.executable, "-m", "pipeline.cli", "fill", str(noskel)], env=env, cwd=tmp_path,
                         capture_output=True, text=True, timeout=60)  # fmt: skip
    assert (
        res.returncode == 2 and res.stderr.count("\n") == 1 and "no SkelRoot holds a skeleton" in res.stderr
    )
    # No worker was started (it writes its log first). Reading the shot costs about 1 s over
    # the CLI's start-up, starting the embedded farm ~8 s more; beside the other test
    # processes a run was once 4.7 s over the floor, so the bound leaves room for that.
    assert not (tmp_path / "cache" / "farm" / "logs").exists()
    assert time.monotonic() - t0 < floor + 6.0
    shot = copy_shot(example_shot(), shots, "roots")
    down = dict(env, TWEEN_BROKER_URL="redis://127.0.0.1:1/0", TWEEN_SHOT_ROOTS=str(shots))
    res = subprocess.run([sys.executable, "-m", "pipeline.cli", "fill", str(shot), "--out-dir", str(tmp_path / "x")],
                         env=down, cwd=tmp_path, capture_output=True, text=True, timeout=60)  # fmt: skip
    assert res.returncode == 2 and res.stderr.count("\n") == 1
    assert "outside the shot roots" in res.stderr and "connect" not in res.stderr


def test_a_shot_linked_from_another_folder_is_filled_where_it_is_given(tmp_path):
    """The embedded farm's roots were the given shots' folders only, while the worker checks
    paths with symlinks followed: a shot linked from another folder was refused as "outside
    the shot roots" (roots the user never set), though `tween fill-local` filled it."""
    real = copy_shot(example_shot(), tmp_path / "real", "linked")
    links = tmp_path / "links"
    links.mkdir()
    (links / real.name).symlink_to(real)
    cmd = [sys.executable, "-m", "pipeline.cli", "fill", str(links / real.name), "--no-progress"]
    res = subprocess.run(cmd, env=_env(tmp_path), cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.startswith(f"{links / real.name}: layer {links / 'linked.tween.v001.usda'}")
    assert sorted(p.name for p in (tmp_path / "real").iterdir()) == ["linked.usda"]


def test_a_shot_in_a_folder_named_with_a_colon_is_filled(tmp_path):
    """The embedded farm gave its worker the shot roots joined by ':' (os.pathsep), so a
    root ``sq:010`` came back as ``sq`` and ``010`` and the shot was refused as outside them."""
    shot = copy_shot(example_shot(), tmp_path / "sq:010", "demo")
    cmd = [sys.executable, "-m", "pipeline.cli", "fill", str(shot), "--model", "interp", "--no-progress"]
    res = subprocess.run(cmd, env=_env(tmp_path), cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-3000:]
    assert (shot.parent / "demo.tween.v001.usda").is_file()


def test_shot_roots_as_a_json_list_keep_a_colon(tmp_path):
    from workers.settings import FarmConfigError, load_settings

    env = {"TWEEN_FARM_CONFIG": os.devnull, "TWEEN_BROKER_URL": "redis://h"}
    roots = [str(tmp_path / "sq:010"), str(tmp_path / "b")]
    assert load_settings({**env, "TWEEN_SHOT_ROOTS": json.dumps(roots)}).shot_roots == tuple(roots)
    for bad in ("[", '["a", 1]', '[""]'):
        with pytest.raises(FarmConfigError, match="TWEEN_SHOT_ROOTS="):
            load_settings({**env, "TWEEN_SHOT_ROOTS": bad})
