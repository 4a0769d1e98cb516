"""Bounded work (issue 17): a long shot fills in windows, with memory that follows the window
and not the shot (and fills up to ``CHUNK_FRAMES`` frames exactly as before); a fill that runs
out of farm time says which limit it hit and where to raise it; a broken model folder is one
line naming the file, never an onnxruntime traceback."""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from usd_fixtures import BANDAI_CLIP

from pipeline.errors import TweenError
from pipeline.infer.folder import model_hash
from pipeline.infer.generator_onnx import CHUNK_FRAMES, ModelFolderError, OnnxInbetweener
from pipeline.motion.bvh import read_bvh
from pipeline.motion.fk import fk
from pipeline.motion.rotations import quat_inv, quat_mul

REPO = Path(__file__).resolve().parents[2]
TESTS = Path(__file__).resolve().parents[1]
DEFAULT = REPO / "models" / "default"


def tiled(frames: int):
    """The Bandai walk played forwards and backwards over and over: ``frames`` frames of real,
    continuous motion (each turn-around is a frame held by the mirrored order)."""
    m = read_bvh(BANDAI_CLIP).continuous()
    fwd = np.arange(len(m))
    idx = np.resize(np.r_[fwd, fwd[-2:0:-1]], frames)
    return replace(m, rotations=m.rotations[idx], root_positions=m.root_positions[idx])


def long_shot(path: Path, frames: int, keys_every: int = 10) -> Path:
    from pipeline.usd.convert import write_shot

    write_shot(tiled(frames), path, keys_every=keys_every)
    return path


def _angle(a, b) -> np.ndarray:
    d = quat_mul(quat_inv(a.astype(np.float64)), b.astype(np.float64))
    return np.degrees(2 * np.arccos(np.clip(np.abs(d[..., 3]), 0, 1)))


@pytest.fixture(scope="module")
def model():
    return OnnxInbetweener(DEFAULT)


# -- memory ----------------------------------------------------------------------------------

# Runs in a child of a child: RUSAGE_CHILDREN of the middle process is the fill's own peak,
# whatever other children the test process had.
MEASURE = """
import resource, subprocess, sys
fill = (
    "import sys; from pipeline.fill.api import FillOptions, fill_shot; "
    "fill_shot(sys.argv[1], FillOptions(model='default', out_dir=sys.argv[2]))"
)
subprocess.run([sys.executable, "-c", fill, sys.argv[1], sys.argv[2]], check=True)
print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)
"""


def _peak_mb(shot: Path, out: Path) -> float:
    env = {**os.environ, "PYTHONPATH": str(REPO), "TWEEN_ORT_THREADS": "1"}
    res = subprocess.run(
        [sys.executable, "-c", MEASURE, str(shot), str(out)],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    return int(res.stdout.split()[-1]) / 1024  # ru_maxrss is in KiB on Linux


def test_long_fill_memory_follows_the_window_not_the_shot(tmp_path):
    """A 20,000-frame shot (a key every 10 frames) against a 2,000-frame one, each filled and
    written with the default model in a process of its own.

    Before windows, the fill built frames x keys tables (the distance of every frame to every
    key in post.lock_feet, 2 x 8 bytes each; every key against every sample in
    solve.rig_key_channels), 2 x 20,000 x 2,001 x 8 B = 640 MB + 64 MB more at 20,000 frames,
    and float64 copies of every per-frame array: 1,004 MB peak against 256 MB for the short
    shot (100,000 frames: 16.5 GB). Now each window is at most ~2,600 frames: the long shot
    costs only its own arrays (the fill's input and output and the USD samples, ~2 KB per
    frame) over the short one."""
    short = long_shot(tmp_path / "short.usda", 2_000)
    long = long_shot(tmp_path / "long.usda", 20_000)
    base = _peak_mb(short, tmp_path / "o1")
    peak = _peak_mb(long, tmp_path / "o2")
    # Today's tables alone are 700 MB over the short shot; windows leave ~50 MB.
    assert peak - base < 200, (base, peak)
    assert peak < 600, (base, peak)


# -- windows ---------------------------------------------------------------------------------


def test_fills_up_to_the_threshold_are_one_window_and_unchanged(model):
    """At CHUNK_FRAMES frames the fill is one window: bitwise what a model that never chunks
    gives (and what every fill gave before windows)."""
    m = tiled(CHUNK_FRAMES)
    keys = np.unique(np.r_[np.arange(0, CHUNK_FRAMES, 10), CHUNK_FRAMES - 1])
    assert model.chunk_plan(CHUNK_FRAMES, keys) == [(0, CHUNK_FRAMES - 1, 0, CHUNK_FRAMES - 1)]
    never = OnnxInbetweener(DEFAULT)
    never.chunk_frames = 10**9
    a, b = model.fill(m, keys), never.fill(m, keys)
    assert np.array_equal(a.rotations, b.rotations) and np.array_equal(a.root_positions, b.root_positions)


@pytest.mark.parametrize(
    "n, every, partial",
    [(9000, 10, False), (20000, 7, False), (9000, 10, True), (12000, 1, False), (9100, 400, False)],
)
def test_chunk_plan_cuts_at_full_keys_and_covers_the_receptive_field(model, n, every, partial):
    keys = np.unique(np.r_[np.arange(3, n - 5, every), n - 5])
    jk = None
    full = keys
    if partial:  # every other key keys the root only: windows must start and end on full keys
        jk = np.ones((len(keys), 22), bool)
        jk[1:-1:2, :21] = False
        full = keys[jk.all(axis=1)]
    plan = model.chunk_plan(n, keys, jk)
    assert len(plan) > 1
    assert plan[0][2] == 0 and plan[-1][3] == n - 1
    for (_, _, _, b), (_, _, a, _) in zip(plan[:-1], plan[1:], strict=True):
        assert a == b and a in full  # kept pieces meet at a full key
    for lo, hi, a, b in plan:
        assert lo <= a <= b <= hi and hi - lo < 2 * model.chunk_core + 2 * model.margin + 2 * every
        assert lo == 0 or (lo in full and a - lo >= model.margin)
        assert hi == n - 1 or (hi in full and hi - b >= model.margin)


def test_a_long_fill_is_continuous_across_windows(model):
    """Past the threshold: keys exact, the pieces meet at keys, and a seam looks like any other
    key (the acceleration there is within what the keys of one window show). Against one
    window over the whole shot the fill differs a little: the network puts each window in the
    frame of its first key, and far from the shot's first key a single window is far outside
    the positions it was trained on (both are as close to the real motion)."""
    n = CHUNK_FRAMES + 1500
    m = tiled(n)
    keys = np.unique(np.r_[np.arange(0, n, 10), n - 1])
    plan = model.chunk_plan(n, keys)
    assert len(plan) >= 4
    out = model.fill(m, keys)
    assert np.array_equal(out.rotations[keys], m.rotations[keys])
    assert np.array_equal(out.root_positions[keys], m.root_positions[keys])
    _, p = fk(out.rotations, out.root_positions, m.skeleton.parents, m.skeleton.offsets)
    acc = np.linalg.norm(p[2:] - 2 * p[1:-1] + p[:-2], axis=-1).max(-1)  # cm / frame², worst joint
    seams = np.array([a for _, _, a, _ in plan[1:]])
    assert acc[seams - 1].max() <= np.percentile(acc[keys[1:-1] - 1], 99.5)
    whole = OnnxInbetweener(DEFAULT)
    whole.chunk_frames = 10**9
    one = whole.fill(m, keys)
    between = ~np.isin(np.arange(n), keys)
    err_w = _angle(m.rotations, out.rotations)[between].mean()
    err_1 = _angle(m.rotations, one.rotations)[between].mean()
    assert err_w < 1.1 * err_1 + 0.5, (err_w, err_1)  # against the real motion: as close


def test_long_gaps_and_partial_keys_go_through_windows(model):
    """Hierarchical key insertion (a 400-frame gap) runs before the windows, and partial keys
    keep their channels: keys exact, every frame finite."""
    n = CHUNK_FRAMES + 900
    m = tiled(n)
    keys = np.unique(np.r_[np.arange(0, 4000, 12), np.arange(4400, n, 12), n - 1])
    jk = np.ones((len(keys), 22), bool)
    jk[5:-5:3, 21] = False  # every third key leaves the root unkeyed
    out = model.fill(m, keys, joint_keys=jk)
    assert np.isfinite(out.rotations).all() and np.isfinite(out.root_positions).all()
    full = jk.all(axis=1)
    assert np.array_equal(out.rotations[keys], m.rotations[keys])
    assert np.array_equal(out.root_positions[keys[full]], m.root_positions[keys[full]])


def test_solve_blocks_and_key_channels_are_exact(tmp_path, monkeypatch):
    """fill_character turning frames back onto the rig in blocks of 7 gives the fill of one
    block, bitwise; the keys' channel test without a keys x samples table is the same test."""
    from pipeline.fill import solve
    from pipeline.fill.api import FillOptions, fill_take, load_take

    shot = long_shot(tmp_path / "s.usda", 300, keys_every=9)
    ref = load_take(fill_take(str(shot), FillOptions(model="default"), 0, str(tmp_path / "a")))
    monkeypatch.setattr(solve, "SOLVE_BLOCK", 7)
    got = load_take(fill_take(str(shot), FillOptions(model="default"), 0, str(tmp_path / "b")))
    for k in ("times", "rot", "trans", "scale"):
        assert np.array_equal(ref["data"][0][k], got["data"][0][k]), k
    rng = np.random.default_rng(0)
    times = np.sort(rng.choice(np.arange(1001, 3000) + rng.choice([0, 1e-5, 3e-4], 1999), 700, replace=False))
    k = np.sort(rng.uniform(1001, 3000, 400).round(0))
    t = np.sort(times)
    i = np.searchsorted(t, k)
    near = np.minimum(np.abs(k - t[np.maximum(i - 1, 0)]), np.abs(k - t[np.minimum(i, len(t) - 1)]))
    assert np.array_equal(near < 1e-4, np.abs(k[:, None] - times[None]).min(axis=1) < 1e-4)


def test_a_fill_range_of_too_many_joint_frames_is_refused_before_it_runs(tmp_path, monkeypatch, capsys):
    """2,000 joints x 100,000 frames (within the frame bound) ran for minutes and then out of
    memory (9.4 GB), an internal error; --range fills such a shot in parts."""
    from pipeline.cli import main
    from pipeline.fill import plan

    def tween(*args) -> tuple[int, list[str]]:
        with pytest.raises(SystemExit) as e:
            main(["fill-local", str(shot), "--model", "interp", *args])
        return e.value.code, capsys.readouterr().err.strip().splitlines()

    shot = long_shot(tmp_path / "s.usda", 300, keys_every=9)  # 21 joints, frames 1001-1300
    monkeypatch.setattr(plan, "MAX_JOINT_FRAMES", 21 * 200)  # as if 200 frames were 4 GB
    code, err = tween("--out-dir", str(tmp_path / "out"))
    assert code == 2 and len(err) == 1, err
    assert "/Anim" in err[0] and "is 300 frames of 21 joints, over 4,200 joint-frames" in err[0]
    assert "fill it in parts with --range" in err[0] and not (tmp_path / "out").exists()
    code, err = tween("--range", "1001-1150", "--out-dir", str(tmp_path / "o"))
    assert code == 0, err


# -- farm time limits ------------------------------------------------------------------------


def test_time_limit_messages_name_the_limit_its_value_and_where_to_raise_it(tmp_path):
    from celery.exceptions import SoftTimeLimitExceeded, TimeLimitExceeded

    from workers.limits import failure_message, soft_limit_error
    from workers.settings import load_settings

    cfg = tmp_path / "farm.toml"
    cfg.write_text("fill_soft_time_limit = 7\nfill_time_limit = 9\n")
    env = {"TWEEN_FARM_CONFIG": str(cfg), "TWEEN_CACHE": str(tmp_path / "cache")}
    s = load_settings(env)
    msg = str(soft_limit_error("/shots/sh010.usda", s, env))
    assert msg == (
        "fill of /shots/sh010.usda hit the farm's soft time limit (fill_soft_time_limit = 7 s); "
        f"raise it in {cfg} or TWEEN_FILL_SOFT_TIME_LIMIT (it must stay below fill_time_limit = 9 s)"
    )
    hard = failure_message(TimeLimitExceeded(9), "/shots/sh010.usda", s, env)
    assert hard == (
        "fill of /shots/sh010.usda hit the farm's hard time limit (fill_time_limit = 9 s); "
        f"raise it in {cfg} or TWEEN_FILL_TIME_LIMIT"
    )
    assert "soft time limit (fill_soft_time_limit = 7 s)" in failure_message(
        SoftTimeLimitExceeded(), "/x", s, env
    )
    assert failure_message(ValueError("/x.usda: bad"), "/x.usda", s, env) == "/x.usda: bad"


def test_a_fill_at_the_soft_limit_fails_with_that_message(tmp_path):
    """The real thing: `tween fill` on the embedded farm with a 2-s soft limit and a take that
    sleeps (tests/farm_slowfill.py): status 2 and the one line."""
    hooks = tmp_path / "hooks"
    hooks.mkdir()
    (hooks / "sitecustomize.py").write_text("import farm_slowfill  # noqa: F401\n")
    shot = tmp_path / "sh010_walk.usda"
    shutil.copyfile(REPO / "examples" / "sh010_walk.usda", shot)
    env = {k: v for k, v in os.environ.items() if not k.startswith("TWEEN_")}
    cfg = tmp_path / "farm.toml"
    cfg.write_text("")  # the studio's (empty) farm config, named as where to raise the limit
    env.update(
        TWEEN_CACHE=str(tmp_path / "cache"),
        TWEEN_FARM_CONFIG=str(cfg),
        TWEEN_FILL_SOFT_TIME_LIMIT="2",
        TWEEN_FILL_TIME_LIMIT="30",
        TWEEN_TEST_FILL_DELAY="60",
        PYTHONPATH=os.pathsep.join([str(hooks), str(TESTS), str(REPO)]),
    )
    if "TWEEN_DATA" in os.environ:
        env["TWEEN_DATA"] = os.environ["TWEEN_DATA"]
    cmd = [sys.executable, "-m", "pipeline.cli", "fill", str(shot), "--model", "interp", "--no-progress"]
    res = subprocess.run(cmd, env=env, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert res.returncode == 2, res.stderr[-3000:]
    assert res.stderr.strip().splitlines() == [
        f"tween: error: fill of {shot} hit the farm's soft time limit (fill_soft_time_limit = 2 s); "
        f"raise it in {cfg} or TWEEN_FILL_SOFT_TIME_LIMIT (it must stay below fill_time_limit = 30 s)"
    ]


# -- broken model folders --------------------------------------------------------------------


def _meta() -> dict:
    return json.loads((DEFAULT / "model.json").read_text())


def _json(**change):
    def make(folder: Path):
        meta = _meta()
        for k, v in change.items():
            if v is None:
                meta.pop(k)
            else:
                meta[k] = v
        (folder / "model.json").write_text(json.dumps(meta))

    return make


def _bytes(name: str, data):
    def make(folder: Path):
        p = folder / name
        p.unlink()
        p.write_bytes(data(DEFAULT / name) if callable(data) else data)

    return make


def _npz(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def _remove(name: str):
    return lambda folder: (folder / name).unlink()


BROKEN = {
    "generator missing": (_remove("generator.onnx"), "generator.onnx", "missing"),
    "generator empty": (_bytes("generator.onnx", b""), "generator.onnx", "empty"),
    "generator half": (_bytes("generator.onnx", lambda p: p.read_bytes()[: p.stat().st_size // 2]), "generator.onnx", "truncated"),
    "generator one byte short": (_bytes("generator.onnx", lambda p: p.read_bytes()[:-1]), "generator.onnx", "truncated"),
    "generator is text": (_bytes("generator.onnx", b"version https://git-lfs.github.com/spec/v1\noid sha256:0\n"), "generator.onnx", "not an ONNX model"),
    "path truncated": (_bytes("path.onnx", lambda p: p.read_bytes()[:100_000]), "path.onnx", "truncated"),
    "model.json missing": (_remove("model.json"), "model.json", "missing"),
    "model.json empty": (_bytes("model.json", b""), "model.json", "not valid JSON"),
    "model.json bad JSON": (_bytes("model.json", b'{"name": "x",}'), "model.json", "not valid JSON (line 1"),
    "model.json not UTF-8": (_bytes("model.json", b'{"name": "\xff"}'), "model.json", "cannot read"),
    "model.json a list": (_bytes("model.json", b"[1, 2]"), "model.json", "expected a JSON object, found an array"),
    "no files": (_json(files=None), "model.json", "missing key(s) 'files'"),
    "no hash": (_json(hash=None), "model.json", "missing key(s) 'hash'"),
    "fps a string": (_json(fps="30"), "model.json", "'fps' must be a number, not a string"),
    "multiple not an integer": (_json(multiple=32.5), "model.json", "'multiple' must be an integer"),
    "multiple zero": (_json(multiple=0), "model.json", "'multiple' must be positive"),
    "generator file a number": (_json(files={"generator": 3}), "model.json", "'files' must name the generator"),
    "feet_anchor a string": (_json(feet_anchor="yes"), "model.json", "'feet_anchor' must be true or false"),
    "min_window negative": (_json(min_window=-4), "model.json", "'min_window' must be 0 to 1024 frames"),
    "pad_tail huge": (_json(pad_tail=10**8), "model.json", "'pad_tail' must be 0 to 1024 frames, not 100000000"),
    "generator config a list": (_json(generator=[1]), "model.json", "'generator' must be an object"),
    "beside a string": (_json(beside="delta"), "model.json", "'beside' must be an array, not a string"),
    "format of a later release": (_json(format=9), "model.json", "'format' is 9; this release reads format 1"),
    "pose bank missing": (_remove("pose_bank.npz"), "pose_bank.npz", "the pose bank model.json names is missing"),
    "pose bank empty": (_bytes("pose_bank.npz", b""), "pose_bank.npz", "not a pose bank"),
    "pose bank truncated": (_bytes("pose_bank.npz", lambda p: p.read_bytes()[: p.stat().st_size // 2]), "pose_bank.npz", "not a pose bank"),
    "pose bank is text": (_bytes("pose_bank.npz", b"not a bank"), "pose_bank.npz", "not a pose bank"),
    "pose bank of another rig": (_bytes("pose_bank.npz", lambda p: _npz(poses=np.zeros((8, 19, 3), np.float16))), "pose_bank.npz", "a pose bank of 19 joints for a model of 21"),
    "pose bank without poses": (_bytes("pose_bank.npz", lambda p: _npz(other=np.zeros(3))), "pose_bank.npz", "not a pose bank"),
    "pose bank a number": (_json(pose_bank=3), "model.json", "pose_bank must be a file name, not 3"),
    "library missing": (_remove("library"), "model.json", "'library' names 'library', which holds no library.json"),
    "library outside the folder": (_json(library="../default"), "model.json", "'library' must be a folder inside the model folder"),
    "library a number": (_json(library=3), "model.json", "'library' must be a string"),
    "familiar credit a string": (_json(familiar_credit="no"), "model.json", "'familiar_credit' must be true or false"),
}  # fmt: skip


def _broken_folder(tmp_path: Path, make) -> Path:
    folder = tmp_path / "broken"
    folder.mkdir()
    shutil.copyfile(DEFAULT / "model.json", folder / "model.json")
    for f in ("generator.onnx", "path.onnx", "pose_bank.npz", "library", "delta"):
        (folder / f).symlink_to(DEFAULT / f)
    make(folder)
    return folder


@pytest.mark.parametrize("case", list(BROKEN))
def test_a_broken_model_folder_is_one_line_naming_the_file(tmp_path, case):
    from pipeline.fill.api import _MODELS, _model

    make, name, says = BROKEN[case]
    folder = _broken_folder(tmp_path, make)
    _MODELS.clear()
    with pytest.raises(TweenError) as ei:
        _model(str(folder))  # what validate_shot and fill_take load a model with
    msg = str(ei.value)
    assert isinstance(ei.value, ModelFolderError)
    assert msg.startswith(f"{folder / name}: ") and says in msg, msg
    assert "\n" not in msg and "onnxruntime" not in msg.lower()


def test_the_cli_prints_a_broken_model_in_one_line_with_status_2(tmp_path):
    folder = _broken_folder(tmp_path, BROKEN["generator half"][0])
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "pipeline.cli", "fill-local", str(REPO / "examples" / "sh010_walk.usda")]
    res = subprocess.run(
        [*cmd, "--model", str(folder), "--out-dir", str(out)],
        env={**os.environ, "PYTHONPATH": str(REPO)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 2
    size = (DEFAULT / "generator.onnx").stat().st_size // 2
    assert res.stderr.strip().splitlines() == [
        f"tween: error: {folder / 'generator.onnx'}: truncated or not an ONNX model ({size} bytes)"
    ]
    assert not out.exists()


@pytest.mark.parametrize(
    "config, says",
    [
        (None, "no 'generator' config, which gives 300"),
        ({"key_adapter": False}, "its 'generator' config, which gives 300"),
    ],
)
def test_a_generator_config_that_does_not_fit_the_network_is_named(tmp_path, config, says):
    """model.json's generator config left out, or edited so the features it gives do not fit
    the ONNX file: one line naming the file at the session's start, not onnxruntime's error."""
    folder = _broken_folder(tmp_path, _json(generator=config))
    with pytest.raises(ModelFolderError) as ei:
        OnnxInbetweener(folder).fill(tiled(40), np.array([0, 20, 39]))
    assert (
        str(ei.value) == f"{folder / 'generator.onnx'}: takes 453 feature channels, but model.json has {says}"
    )


@pytest.mark.parametrize("dna", [8, -1, "x", True])
def test_a_dna_size_the_network_does_not_take_is_named(tmp_path, dna):
    """generator.dna edited on a network without DNA inputs (or to no whole number): the
    fill failed inside onnxruntime ("Invalid input name: dna_weight"), an internal error."""
    gen = {**_meta()["generator"], "dna": dna}
    folder = _broken_folder(tmp_path, _json(generator=gen))
    with pytest.raises(ModelFolderError) as ei:
        OnnxInbetweener(folder).fill(tiled(40), np.array([0, 20, 39]))
    assert (
        str(ei.value)
        == f"{folder / 'generator.onnx'}: takes no motion DNA, but model.json's generator.dna is {dna!r} (0 or absent)"
    )


def _rehash(folder: Path) -> None:
    """model.json's hash made to fit the folder's files, as an export would state it."""
    meta = json.loads((folder / "model.json").read_text())
    (folder / "model.json").write_text(json.dumps(meta | {"hash": model_hash(folder, meta)}))


def test_a_file_changed_after_export_is_refused_at_load_naming_model_json(tmp_path):
    """Every layer records the model's hash; a generator.onnx swapped after the export filled
    under the exported model's hash (the hash was read from model.json, not computed)."""
    folder = _broken_folder(tmp_path, _remove("generator.onnx"))
    shutil.copyfile(DEFAULT / "generator.onnx", folder / "generator.onnx")
    OnnxInbetweener(folder)  # the same bytes: the same model
    with (folder / "generator.onnx").open("r+b") as f:  # one weight's byte changed
        f.seek(-100, 2)
        b = f.read(1)
        f.seek(-100, 2)
        f.write(bytes([b[0] ^ 1]))
    with pytest.raises(ModelFolderError) as ei:
        OnnxInbetweener(folder)
    msg = str(ei.value)
    assert msg.startswith(f"{folder / 'model.json'}: 'hash' is '{_meta()['hash']}' but its files")
    assert "export the model again" in msg and "\n" not in msg
    _rehash(folder)  # exported again: it loads, under its own hash
    assert OnnxInbetweener(folder).model_hash != _meta()["hash"]


def test_a_hashed_setting_changed_after_export_is_refused_at_load(tmp_path):
    """familiar_credit (in the hash: it changes what a fill gives) edited by hand."""
    folder = _broken_folder(tmp_path, _json(familiar_credit=False))
    with pytest.raises(ModelFolderError, match=r"model.json: 'hash' is .* but its files and settings"):
        OnnxInbetweener(folder)


def test_an_onnx_file_of_another_network_is_named_when_its_session_starts(tmp_path):
    """A whole ONNX file that is not this network (the path predictor under the generator's
    name, in a folder whose hash states it) passes the load-time checks; its session names it
    instead of a shape error."""
    folder = _broken_folder(tmp_path, _remove("generator.onnx"))
    (folder / "generator.onnx").symlink_to(DEFAULT / "path.onnx")
    _rehash(folder)
    inb = OnnxInbetweener(folder)
    m = tiled(40)
    with pytest.raises(ModelFolderError, match=r"generator.onnx: not this model's generator"):
        inb.fill(m, np.array([0, 20, 39]))
