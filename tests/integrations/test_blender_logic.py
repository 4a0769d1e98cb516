"""The Blender extension's plain-Python side (integrations/blender), without ``bpy``: the
``tween`` command lines, their output read back, take names, the fill's JSON, the USD text
edits of Blender's export and the fill layer's takes, and the non-blocking job."""

from __future__ import annotations

import importlib.util
import json
import os
import stat
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from blender_fixtures import FRAMES, build_blender_shot, joint_paths

REPO = Path(__file__).resolve().parents[2]
EXT = REPO / "integrations" / "blender"


def _load():
    """The extension as a package, as Blender imports it (its __init__ imports no bpy)."""
    name = "usd_tween_ext"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(
        name, EXT / "__init__.py", submodule_search_locations=[str(EXT)]
    )
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


ext = _load()
from usd_tween_ext import commands, jobs, naming, result, status, usda  # noqa: E402


def test_the_package_imports_without_bpy():
    assert "bpy" not in sys.modules
    assert callable(ext.register) and callable(ext.unregister)
    manifest = (EXT / "blender_manifest.toml").read_text()
    import tomllib

    m = tomllib.loads(manifest)
    assert m["id"] == "usd_tween" and m["type"] == "add-on" and m["blender_version_min"] >= "4.2.0"
    assert not m["tagline"].endswith((".", "!")) and len(m["tagline"]) <= 64  # Blender refuses these


# --- command lines -------------------------------------------------------------------------


def _exe(tmp_path, body: str = "exit 0") -> str:
    p = tmp_path / "tween"
    p.write_text(f"#!/bin/sh\n{body}\n")
    p.chmod(p.stat().st_mode | stat.S_IXUSR)
    return str(p)


def test_fill_and_submit_command_lines(tmp_path):
    exe = _exe(tmp_path)
    s = commands.Settings(
        tween=exe, out_dir=str(tmp_path), takes=4, model="tween-bandai-v5.3", trust="spline"
    )
    assert commands.check(s) is None
    assert commands.fill_command(s, "/s/sh.usda", "/s/out") == [
        exe, "fill", "/s/sh.usda", "--out-dir", "/s/out", "--takes", "4", "--model", "tween-bandai-v5.3",
        "--trust", "spline", "--format", "usda",
    ]  # fmt: skip
    s.farm, s.render = "FARM", True
    assert commands.fill_command(s, "/s/sh.usda", "/s/out")[1] == "submit"
    assert commands.fill_command(s, "/s/sh.usda", "/s/out")[-1] == "--render"
    mapping = tmp_path / "map.json"
    mapping.write_text("{}")
    s.mapping = str(mapping)
    assert commands.check(s) is None and commands.fill_command(s, "/s", "/o")[-2:] == [
        "--mapping",
        str(mapping),
    ]
    s.mapping = str(tmp_path / "nope.json")
    assert commands.check(s) == f"mapping file {s.mapping!r}: no such file"
    assert commands.status_command(s, "ab" * 16) == [exe, "status", "--json", "ab" * 16]
    assert commands.approve_command(s, "/s/sh.usda", "/s/out", 2, "  arms\nlater  ") == [
        exe, "approve", "/s/sh.usda", "--take", "2", "--out-dir", "/s/out", "--note", "arms later"]  # fmt: skip
    assert "--note" not in commands.approve_command(s, "/s/sh.usda", "/s/out", 0, " ")
    assert commands.publish_command(s, "/s/sh.usda", "/s/out") == [
        exe,
        "publish",
        "/s/sh.usda",
        "--out-dir",
        "/s/out",
    ]
    assert commands.review_command(s, "/r.usda", None, "/o")[-2:] == ["-o", "/o"]
    assert commands.review_command(s, "/r.usda", 1, "/o")[-2:] == ["--take", "1"]


@pytest.mark.parametrize(
    "change, says",
    [
        ({"tween": "/no/such/tween"}, "tween executable '/no/such/tween' not found"),
        ({"tween": "no-such-tween-on-path"}, "not found"),
        ({"takes": 0}, "takes 0: from 1 to 64"),
        ({"takes": 65}, "takes 65"),
        ({"trust": "maybe"}, "trust 'maybe'"),
        ({"farm": "CLOUD"}, "farm 'CLOUD'"),
        ({"model": " "}, "model: empty"),
        ({"out_dir": ""}, "output folder: not set"),
    ],
)
def test_bad_settings_are_one_line(tmp_path, change, says):
    s = commands.Settings(tween=_exe(tmp_path), out_dir=str(tmp_path))
    for k, v in change.items():
        setattr(s, k, v)
    line = commands.check(s)
    assert line is not None and says in line and "\n" not in line


def test_environment_has_no_blender_python_and_the_farm_it_is_told():
    base = {
        "PYTHONHOME": "/blender/python",
        "PYTHONPATH": "/x",
        "TWEEN_BROKER_URL": "redis://old",
        "HOME": "/h",
    }
    env = commands.environment(commands.Settings(farm="EMBEDDED"), base)
    assert "PYTHONHOME" not in env and "PYTHONPATH" not in env and "TWEEN_BROKER_URL" not in env
    assert env["HOME"] == "/h" and env["PYTHONUNBUFFERED"] == "1"
    env = commands.environment(commands.Settings(farm="FARM", broker_url=" redis://farm:6379/0 "), base)
    assert env["TWEEN_BROKER_URL"] == "redis://farm:6379/0"
    assert commands.environment(commands.Settings(farm="FARM"), base)["TWEEN_BROKER_URL"] == "redis://old"


def test_output_read_back():
    job = "0123456789abcdef" * 2
    assert commands.submitted_ids(f"{job}\nnoise\n{'f' * 32}\n") == [job, "f" * 32]
    assert commands.submitted_id(f"warming up\ntween: job {job} submitted (/s/sh.usda)\n") == job
    assert commands.submitted_id("tween: /s/sh.usda: job abc") is None
    err = f"tween: job {job} submitted (/s)\ntween: error: /s/sh.usda: no animated skeleton\n"
    assert commands.error_line(err) == "/s/sh.usda: no animated skeleton"
    tb = "Traceback (most recent call last):\n  File x\nRuntimeError: boom\n"
    assert commands.error_line(tb) == "RuntimeError: boom"
    assert commands.error_line("", "", 3) == "tween exited with status 3"
    long = commands.error_line("tween: error: " + "x" * 1000)
    assert len(long) == 400 and long.endswith("…")
    assert commands.published_layer("/o/sh.publish.v001.usda\n") == "/o/sh.publish.v001.usda"


# --- status, names, the fill's JSON ----------------------------------------------------------


def test_status_lines():
    job = "a" * 32
    line = json.dumps({"id": job, "shot": "/s", "state": "RUNNING", "done": 2, "total": 5, "stage": "take1",
                       "error": None, "result": None})  # fmt: skip
    st = status.parse_status(f"some warning\n{line}\n", job)
    assert (st.state, st.fraction, st.finished) == ("RUNNING", 0.4, False)
    assert st.text() == "running take1 (2/5 stages)"
    done = status.parse_status(json.dumps({"id": job, "state": "SUCCESS", "result": {"layer": "/l"}}), job)
    assert done.finished and done.fraction == 1.0 and done.result == {"layer": "/l"} and done.text() == "done"
    bad = status.parse_status(json.dumps({"id": job, "state": "FAILURE", "error": "why"}), job)
    assert bad.text() == "failure: why"
    with pytest.raises(ValueError, match=f"said nothing about job {'b' * 32}"):
        status.parse_status(line, "b" * 32)


def test_take_names():
    assert naming.shot_name("/p/sh010 hero.blend", "Armature.001") == "sh010_hero_Armature_001"
    assert naming.shot_name("", "rig") == "rig" and naming.safe("...") == "shot"
    name = naming.take_action_name("sh010_hero", 2, 1)
    assert name == "sh010_hero.v002.take1"
    assert naming.parse_take_name(name) == ("sh010_hero", 2, 1)
    assert naming.parse_take_name(name + ".001") is None  # Blender's copy of it: the animator's
    assert naming.parse_take_name("walk") is None
    long = naming.take_action_name("s" * 80, 12, 3)
    assert len(long) <= naming.MAX_NAME and naming.parse_take_name(long).version == 12


def test_the_fills_json(tmp_path):
    d = {"layer": "out/sh.tween.v003.usda", "review": "out/sh.review.v003.usda", "version": 3, "takes": 3,
         "model": "m", "same_as": {"2": 1},
         "trust": {"/A": {"choice": "blend", "weight": 0.6, "reason": "because"}},
         "renders": [{"mp4": "r/t0.mp4", "contact_sheet": "r/t0.png", "timeline": "r/sh.otio"}, {"mp4": "r/t1.mp4"},
                     {"same_as": 1}]}  # fmt: skip
    r = result.read_result(d, "/shots")
    assert r.layer == "/shots/out/sh.tween.v003.usda" and r.version == 3 and r.reason == "because"
    assert [t.decision for t in r.takes] == ["blend 0.60"] * 3
    assert (
        r.takes[0].mp4 == "/shots/r/t0.mp4" and r.takes[2].same_as == 1 and r.timeline == "/shots/r/sh.otio"
    )
    assert result.decision({"choice": "spline", "weight": 0.0}) == "spline" and result.decision(None) == ""
    with pytest.raises(ValueError, match="names no layer"):
        result.read_result({"state": "x"})


# --- USD text: Blender's export kept on the keys, the fill layer's takes ---------------------


@pytest.fixture(scope="module")
def blender_export(tmp_path_factory) -> Path:
    """A shot as Blender's USD exporter writes it: a sample on every frame 1..FRAMES."""
    return Path(build_blender_shot(tmp_path_factory.mktemp("bl") / "blocking.usda")["path"])


def _read(path):
    from pipeline.usd.read import read_shot

    return read_shot(path).characters[0]


def test_keep_keys_gives_the_fill_the_blocking(blender_export, tmp_path):
    keys = list(range(1, FRAMES + 1, 10)) + [FRAMES]
    text = blender_export.read_text()
    assert usda.animation_joints(text) == joint_paths()
    joints = joint_paths()
    partial = {21: joints[:6], 31: []}  # the torso only; then a key of the root's position only
    out = tmp_path / "keys.usda"
    out.write_text(usda.keep_keys(text, keys, located=[1, 31, FRAMES], keyed_joints=partial))
    c = _read(out)
    assert c.rot_times.tolist() == [float(k) for k in sorted(set(keys))]
    assert c.trans_times.tolist() == [1.0, 31.0, float(FRAMES)]
    assert c.keyed_joints == {21.0: tuple(joints[:6]), 31.0: ()}
    got_joints, samples = usda.read_samples(out.read_text())
    assert got_joints == joints and sorted(samples["rotations"]) == c.rot_times.tolist()
    # the kept samples are Blender's, unchanged
    from pxr import Usd, UsdSkel

    stages = [Usd.Stage.Open(str(p)) for p in (blender_export, out)]  # kept open while read
    a, b = (UsdSkel.Animation(st.GetPrimAtPath("/root/Armature/Armature/Anim")) for st in stages)
    for t in (1, 21, FRAMES):
        assert np.array_equal(np.array(a.GetRotationsAttr().Get(t)), np.array(b.GetRotationsAttr().Get(t)))


def test_keep_keys_refuses_in_one_line(blender_export):
    text = blender_export.read_text()
    with pytest.raises(ValueError, match="1 keyed frame"):
        usda.keep_keys(text, [5])
    with pytest.raises(ValueError, match="'nope' is not a joint of the animation"):
        usda.keep_keys(text, [1, 11], keyed_joints={11: ["nope"]})
    with pytest.raises(ValueError, match="expected one SkelAnimation in the file, found 0"):
        usda.keep_keys("#usda 1.0\n", [1, 2])


@pytest.mark.parametrize("takes", [1, 2])
def test_the_fill_layers_takes_read_back(blender_export, tmp_path, takes):
    from pxr import Usd, UsdSkel

    from pipeline.fill.api import FillOptions, fill_shot

    shot = tmp_path / "sh.usda"
    shot.write_text(usda.keep_keys(blender_export.read_text(), list(range(1, FRAMES + 1, 10)) + [FRAMES]))
    r = fill_shot(str(shot), FillOptions(model="interp", takes=takes, out_dir=str(tmp_path / "out")))
    text = Path(r["layer"]).read_text()
    joints, got = usda.read_takes(text, "Anim")
    # what the layer itself says, for a fill Blender no longer follows (Fetch latest)
    said = usda.layer_result(text)
    assert (said["version"], said["takes"], said["review"]) == (1, takes, Path(r["review"]).name)
    want = next(iter(r["trust"].values())) or {}
    assert said["trust"]["Anim_tween"]["choice"] == want.get("choice", "")
    names = [
        "sh.tween.v002.usda",
        "sh.tween.v010.usda",
        "sh.review.v011.usda",
        "shx.tween.v099.usda",
        "sh.usda",
    ]
    assert (
        usda.latest_layer(names, "sh") == (10, "sh.tween.v010.usda")
        and usda.latest_layer(names, "no") is None
    )
    assert joints == joint_paths() and sorted(got) == list(range(takes))
    stage = Usd.Stage.Open(r["review"])
    for n in range(takes):
        if takes > 1:
            stage.GetPrimAtPath("/root").GetVariantSet("tweenTake").SetVariantSelection(f"take{n}")
        anim = UsdSkel.Animation(stage.GetPrimAtPath("/root/Armature/Armature/Anim_tween"))
        times = anim.GetRotationsAttr().GetTimeSamples()
        assert sorted(got[n]["rotations"]) == times and len(times) == FRAMES
        for t in (1.0, 5.0, 133.0):
            q = np.array([(x.real, *x.imaginary) for x in anim.GetRotationsAttr().Get(t)], np.float32)
            assert np.array_equal(np.array(got[n]["rotations"][t], np.float32), q)
            tr = np.array(anim.GetTranslationsAttr().Get(t), np.float32)
            assert np.array_equal(np.array(got[n]["translations"][t], np.float32), tr)


# --- the job: never waits, says its state, fails in one line --------------------------------

_FAKE = r'''#!{py}
"""A stand-in tween: fill says its job id and waits; status answers from a file."""
import json, os, sys, time
state = os.path.join(os.path.dirname(__file__), "state.json")
verb = sys.argv[1]
if verb == "fill":
    if "--takes" in sys.argv and sys.argv[sys.argv.index("--takes") + 1] == "9":
        print("tween: error: sh.usda: joints do not map onto the model skeleton; write them", file=sys.stderr)
        sys.exit(2)
    print("tween: job " + "c" * 32 + " submitted (sh.usda)", file=sys.stderr, flush=True)
    while json.load(open(state))["state"] != "SUCCESS":
        time.sleep(0.05)
elif verb == "submit":
    print("d" * 32)
elif verb == "status":
    d = json.load(open(state)); d["id"] = sys.argv[-1]
    print(json.dumps(d))
'''


def _fake(tmp_path, state: dict) -> str:
    exe = tmp_path / "tween"
    exe.write_text(_FAKE.replace("{py}", sys.executable))
    exe.chmod(0o755)
    (tmp_path / "state.json").write_text(json.dumps(state))
    return str(exe)


def _until(job, want, timeout=30.0):
    t0 = time.monotonic()
    while job.state not in want:
        assert time.monotonic() - t0 < timeout, job.text()
        job.tick()
        time.sleep(0.02)


@pytest.mark.parametrize("farm", ["EMBEDDED", "FARM"])
def test_a_fill_job_polls_until_its_result(tmp_path, farm):
    exe = _fake(tmp_path, {"state": "RUNNING", "done": 1, "total": 4, "stage": "take0"})
    s = commands.Settings(tween=exe, farm=farm, out_dir=str(tmp_path))
    t0 = time.monotonic()
    job = jobs.FillJob(s, str(tmp_path / "sh.usda"), str(tmp_path), str(tmp_path / "log"), interval=0.05)
    assert job.tick() in ("starting", "running") and time.monotonic() - t0 < 2.0  # returns at once
    _until(job, ("running",))
    assert job.job_id == ("c" if farm == "EMBEDDED" else "d") * 32
    while job.status is None:
        job.tick()
        time.sleep(0.02)
    assert job.text() == "running take0 (1/4 stages)" and job.fraction == 0.25
    (tmp_path / "state.json").write_text(
        json.dumps({"state": "SUCCESS", "done": 4, "total": 4, "result": {"layer": "l"}})
    )
    _until(job, ("done", "failed"))
    assert job.state == "done" and job.result == {"layer": "l"}
    job.proc.proc.wait(10)


def test_a_fill_that_fails_says_one_line(tmp_path):
    exe = _fake(tmp_path, {"state": "RUNNING"})
    s = commands.Settings(tween=exe, takes=9, out_dir=str(tmp_path))
    job = jobs.FillJob(s, str(tmp_path / "sh.usda"), str(tmp_path), str(tmp_path / "log"), interval=0.05)
    _until(job, ("failed",))
    assert job.error == "sh.usda: joints do not map onto the model skeleton; write them"
    (tmp_path / "state.json").write_text(
        json.dumps({"state": "FAILURE", "error": "take1 failed: out of memory"})
    )
    s.takes = 2
    job = jobs.FillJob(s, str(tmp_path / "sh.usda"), str(tmp_path), str(tmp_path / "log"), interval=0.05)
    _until(job, ("failed",))
    assert job.error == "take1 failed: out of memory"
    job.proc.proc.kill()


def test_a_tween_that_cannot_run_is_one_line(tmp_path):
    s = commands.Settings(tween=str(tmp_path / "missing"), out_dir=str(tmp_path))
    with pytest.raises(ValueError, match="cannot run .*missing"):
        jobs.FillJob(s, "sh.usda", str(tmp_path), str(tmp_path / "log"))


def _tween() -> Path:
    exe = Path(sys.executable).parent / "tween"
    if not exe.is_file():
        pytest.skip(f"no tween executable beside {sys.executable}")
    return exe


def test_the_real_tween_fill_says_its_job_and_status_follows_it(tmp_path, monkeypatch):
    """The embedded farm of the project's own `tween` (no Blender): the id said at submission,
    `tween status` polled until the fill's JSON, the takes read back from its layer."""
    exe = _tween()
    monkeypatch.setenv("TWEEN_FARM_CONFIG", os.devnull)  # embedded, whatever this machine's config says
    monkeypatch.setenv("TWEEN_CACHE", str(tmp_path / "cache"))
    shot = tmp_path / "sh.usda"
    build = build_blender_shot(tmp_path / "export.usda")
    shot.write_text(
        usda.keep_keys(Path(build["path"]).read_text(), list(range(1, FRAMES + 1, 20)) + [FRAMES])
    )
    s = commands.Settings(tween=str(exe), out_dir=str(tmp_path / "out"), takes=2, model="interp")
    job = jobs.FillJob(s, str(shot), s.out_dir, str(tmp_path / "log"), interval=0.5)
    _until(job, ("done", "failed"), timeout=240)
    assert job.state == "done", job.error
    r = result.read_result(job.result, str(tmp_path))
    assert r.version == 1 and len(r.takes) == 2 and Path(r.layer).is_file()
    joints, takes = usda.read_takes(Path(r.layer).read_text(), "Anim")
    assert sorted(takes) == [0, 1] and len(joints) == len(joint_paths())


def test_a_fill_through_a_real_broker(tmp_path, monkeypatch):
    """Broker mode: `tween submit` to a Redis farm with a real worker, `tween status` polled
    until the fill's JSON."""
    exe = _tween()
    from redis_server import WorkerPool, farm_env, start_redis

    server = start_redis()
    root = tmp_path / "shots"
    root.mkdir()
    env = farm_env(server, [str(root)])
    env["PYTHONPATH"] = str(REPO)
    (tmp_path / "logs").mkdir()
    pool = WorkerPool(env, tmp_path / "logs")
    try:
        pool.start(concurrency=1)
        pool.wait_ready()
        for k, v in env.items():
            if k != "TWEEN_BROKER_URL":  # the preference gives the broker
                monkeypatch.setenv(k, v)
        monkeypatch.delenv("TWEEN_BROKER_URL", raising=False)
        shot = root / "sh.usda"
        build = build_blender_shot(tmp_path / "export.usda")
        shot.write_text(
            usda.keep_keys(Path(build["path"]).read_text(), list(range(1, FRAMES + 1, 20)) + [FRAMES])
        )
        s = commands.Settings(tween=str(exe), farm="FARM", broker_url=server.url, out_dir=str(root / "out"),
                              takes=2, model="interp")  # fmt: skip
        job = jobs.FillJob(s, str(shot), s.out_dir, str(tmp_path / "log"), interval=0.3)
        _until(job, ("done", "failed"), timeout=240)
        assert job.state == "done", job.error
        assert job.proc.poll() == 0 and commands.submitted_ids(job.proc.stdout()) == [job.job_id]
        r = result.read_result(job.result, str(root))
        assert sorted(usda.read_takes(Path(r.layer).read_text())[1]) == [0, 1]
        # a shot outside the farm's roots: refused by `tween submit`, in one line
        s.out_dir = str(tmp_path / "elsewhere")
        job = jobs.FillJob(s, str(tmp_path / "export.usda"), s.out_dir, str(tmp_path / "log"), interval=0.3)
        _until(job, ("failed",), timeout=60)
        assert "\n" not in job.error and "root" in job.error, job.error
    finally:
        pool.stop_all()
        server.cleanup()
