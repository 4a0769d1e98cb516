"""Bad options of the `tween` CLIs (issue 17): each one is ONE line on stderr, `tween: error: ...`,
naming the option (or the file, or the broker with its password hidden), with exit status 2,
nothing on stdout, no file written and the shot untouched.

Every case runs the real entry point in a folder holding a small valid shot; the options are
refused before any model is loaded or any farm is started. The farm cases run in a subprocess
(the broker connection, its retries and its time are part of what they check) against brokers on
a closed loopback port (127.0.0.1:1), so they never reach a real server; the others call the same
``main`` in this process (Python's start-up, a second a case, is all a subprocess would add).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from usd_fixtures import bandai_shot

REDIS_DOWN = {"TWEEN_BROKER_URL": "redis://:secret@127.0.0.1:1/0"}
REDIS_SHOWN = "redis://:***@127.0.0.1:1/0"
AMQP_DOWN = {"TWEEN_BROKER_URL": "amqp://guest:secret@127.0.0.1:1//", "TWEEN_RESULT_BACKEND": "redis://:secret@127.0.0.1:1/0"}  # fmt: skip
AMQP_SHOWN = "amqp://guest:***@127.0.0.1:1//"
JOB = "0123456789abcdef0123456789abcdef"

# (id, arguments, extra environment, what the line must name)
CASES = [
    # tween fill: seeds (take k uses seed + k, stored as a 32-bit int), takes, format, DNA poses
    ("fill-seed-negative", ["fill", "s.usda", "--seed", "-1"], {}, "--seed"),
    ("fill-seed-2^31", ["fill", "s.usda", "--seed", "2147483648"], {}, "--seed"),
    ("fill-seed-last-take", ["fill", "s.usda", "--seed", "2147483647", "--takes", "2"], {}, "--seed"),
    ("fill-seed-huge", ["fill", "s.usda", "--seed", "99999999999999999999999"], {}, "--seed"),
    ("fill-seed-text", ["fill", "s.usda", "--seed", "abc"], {}, "--seed"),
    ("fill-takes-0", ["fill", "s.usda", "--takes", "0"], {}, "--takes"),
    ("fill-takes-10000", ["fill", "s.usda", "--takes", "10000"], {}, "--takes"),
    ("fill-takes-negative", ["fill", "s.usda", "--takes", "-3"], {}, "--takes"),
    ("fill-takes-float", ["fill", "s.usda", "--takes", "1.5"], {}, "--takes"),
    ("fill-format", ["fill", "s.usda", "--format", "fbx"], {}, "--format"),
    ("fill-dna-poses-0", ["fill", "s.usda", "--dna-poses", "0"], {}, "--dna-poses"),
    ("fill-dna-poses-9", ["fill", "s.usda", "--dna-poses", "9"], {}, "--dna-poses"),
    ("fill-keys-nan", ["fill", "s.usda", "--keys", "nan"], {}, "--keys"),
    ("fill-keys-inf", ["fill", "s.usda", "--keys", "1001,inf"], {}, "--keys"),
    ("fill-range-nan", ["fill", "s.usda", "--range", "nan-1010"], {}, "--range"),
    ("fill-concurrency-0", ["fill", "s.usda", "-c", "0"], {}, "--concurrency"),
    ("fill-unknown-option", ["fill", "s.usda", "--bogus"], {}, "--bogus"),
    ("fill-no-shot", ["fill"], {}, "shots"),
    ("fill-missing-shot", ["fill", "missing.usda"], {}, "missing.usda"),
    ("fill-local-takes-0", ["fill-local", "s.usda", "--takes", "0"], {}, "--takes"),
    ("fill-local-seed", ["fill-local", "s.usda", "--seed", "-1"], {}, "--seed"),
    ("fill-local-format", ["fill-local", "s.usda", "--format", "abc"], {}, "--format"),
    (
        "fill-library-spline",
        ["fill", "s.usda", "--library", "lib", "--model", "spline"],
        {},
        "--model spline is no network",
    ),
    ("unknown-command", ["nosuch"], {}, "nosuch"),
    # the farm: options first, then the broker (fast, one line, password hidden)
    ("submit-takes-0", ["submit", "s.usda", "--takes", "0"], REDIS_DOWN, "--takes"),
    ("submit-redis-down", ["submit", "s.usda"], REDIS_DOWN, REDIS_SHOWN),
    (
        "submit-library-interp",
        ["submit", "s.usda", "--library", "lib", "--model", "interp"],
        REDIS_DOWN,
        "--model interp is no network",
    ),
    # What the local commands refuse, refused before the job is sent (before: the worker failed).
    (
        "submit-not-a-library",
        ["submit", "s.usda", "--library", "nolib"],
        REDIS_DOWN,
        "nolib: no such library folder",
    ),
    (
        "submit-library-out-not-empty",
        ["submit-library", ".", "--out", "."],
        REDIS_DOWN,
        ".: not empty; use --add",
    ),
    (
        "submit-library-no-takes",
        ["submit-library", "nowhere", "--out", "lib"],
        REDIS_DOWN,
        "no such folder of takes",
    ),
    (
        "train-rig-finished-model",
        [
            "submit-train-rig",
            "s.usda",
            "--out",
            str(Path(__file__).resolve().parents[2] / "models" / "default"),
        ],
        REDIS_DOWN,
        "holds a finished model (model.json); give --force",
    ),  # fmt: skip
    ("status-redis-down", ["status", JOB], REDIS_DOWN, REDIS_SHOWN),
    ("worker-redis-down", ["worker", "-c", "1"], REDIS_DOWN, REDIS_SHOWN),
    ("fill-redis-down", ["fill", "s.usda", "--no-progress"], REDIS_DOWN, REDIS_SHOWN),
    ("train-rig-redis-down", ["submit-train-rig", "s.usda", "--out", "m"], REDIS_DOWN, REDIS_SHOWN),
    # A job the worker could only fail, and that nothing could withdraw (cancel takes fill jobs).
    (
        "train-rig-read-only-out",
        ["submit-train-rig", "s.usda", "--out", "/proc/m"],
        REDIS_DOWN,
        "/proc/m: --out is in /proc, which is read-only",
    ),
    ("submit-amqp-down", ["submit", "s.usda"], AMQP_DOWN, AMQP_SHOWN),
    ("worker-amqp-down", ["worker", "-c", "1"], AMQP_DOWN, AMQP_SHOWN),
    ("status-backend-down", ["status", JOB], AMQP_DOWN, REDIS_SHOWN),
    ("worker-concurrency-0", ["worker", "-c", "0"], REDIS_DOWN, "--concurrency"),
    ("worker-loglevel", ["worker", "--loglevel", "loud"], REDIS_DOWN, "--loglevel"),
    (
        "train-rig-schedule",
        ["submit-train-rig", "s.usda", "--out", "m", "--schedule", "huge"],
        REDIS_DOWN,
        "--schedule",
    ),  # fmt: skip
    (
        "train-rig-threads",
        ["submit-train-rig", "s.usda", "--out", "m", "--threads", "0"],
        REDIS_DOWN,
        "--threads",
    ),  # fmt: skip
    (
        "train-rig-seed",
        ["submit-train-rig", "s.usda", "--out", "m", "--seed", "-1"],
        REDIS_DOWN,
        "--seed",
    ),  # fmt: skip
    (
        "train-rig-device",
        ["submit-train-rig", "s.usda", "--out", "m", "--device", "tpu"],
        REDIS_DOWN,
        "--device",
    ),  # fmt: skip
    ("bench-farm-workers", ["bench-farm", "--workers", "a,b"], {}, "--workers"),
    # tween review: size (even, 16..7680), finite floats, frames, take, camera
    ("review-fills-empty", ["review", "s.usda", "--fills", ""], {}, "--fills ''"),  # was the working folder
    ("review-size-huge", ["review", "s.usda", "--size", "100000x100000"], {}, "--size"),
    ("review-size-0", ["review", "s.usda", "--size", "0x0"], {}, "--size"),
    ("review-size-text", ["review", "s.usda", "--size", "abc"], {}, "--size"),
    ("review-size-negative", ["review", "s.usda", "--size", "-320x240"], {}, "--size"),
    ("review-size-odd", ["review", "s.usda", "--size", "161x90"], {}, "--size"),
    ("review-turns-nan", ["review", "s.usda", "--turns", "nan"], {}, "--turns"),
    ("review-turns-inf", ["review", "s.usda", "--turns", "inf"], {}, "--turns"),
    ("review-turns--inf", ["review", "s.usda", "--turns=-inf"], {}, "--turns"),
    ("review-turns-text", ["review", "s.usda", "--turns", "abc"], {}, "--turns"),
    ("review-frames-nan", ["review", "s.usda", "--frames", "nan:1010"], {}, "--frames"),
    ("review-frames-reversed", ["review", "s.usda", "--frames", "1010:1001"], {}, "--frames"),
    ("review-take-negative", ["review", "s.usda", "--take", "-1"], {}, "--take"),
    ("review-camera", ["review", "s.usda", "--camera", "top"], {}, "--camera"),
    ("review-no-shot", ["review"], {}, "shot"),
]


@pytest.fixture(scope="module")
def shot_bytes(tmp_path_factory) -> bytes:
    return bandai_shot(tmp_path_factory.mktemp("shot") / "s.usda", frames=21, keys_every=10).read_bytes()


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("cache")


def listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def run_case(folder: Path, shot_bytes: bytes, cache: Path, args: list[str], env: dict) -> dict:
    """Runs ``tween ARGS`` in ``folder`` (holding the shot) with only ``env``'s farm settings."""
    folder.mkdir()
    (folder / "s.usda").write_bytes(shot_bytes)
    before = listing(folder)
    run_env = {k: v for k, v in os.environ.items() if not k.startswith("TWEEN_")}
    run_env.update(TWEEN_CACHE=str(cache), TWEEN_FARM_CONFIG=os.devnull, **env)
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", *args], cwd=folder, env=run_env,
                       capture_output=True, text=True, timeout=60)  # fmt: skip
    return dict(folder=folder, before=before, r=r, took=time.monotonic() - t0)


@pytest.fixture(scope="module")
def results(tmp_path_factory, shot_bytes, cache) -> dict:
    """Every farm case's run, four at a time (most of a run is Python starting up, or a broker
    connection being refused and retried), so the whole file stays well under a minute."""
    from concurrent.futures import ThreadPoolExecutor

    root = tmp_path_factory.mktemp("cases")
    with ThreadPoolExecutor(4) as pool:
        futures = {
            cid: pool.submit(run_case, root / f"case{i:02d}", shot_bytes, cache, args, env)
            for i, (cid, args, env, _) in enumerate(CASES)
            if env
        }
        return {cid: f.result() for cid, f in futures.items()}


def run_in_process(
    folder: Path, shot_bytes: bytes, cache: Path, args: list[str], monkeypatch, capsys
) -> dict:
    """:func:`run_case` without a new Python: ``pipeline.cli.main`` in ``folder``."""
    from pipeline.cli import main

    folder.mkdir()
    (folder / "s.usda").write_bytes(shot_bytes)
    before = listing(folder)
    for k in [k for k in os.environ if k.startswith("TWEEN_")]:
        monkeypatch.delenv(k)
    monkeypatch.setenv("TWEEN_CACHE", str(cache))
    monkeypatch.setenv("TWEEN_FARM_CONFIG", os.devnull)
    monkeypatch.chdir(folder)
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main(args)
    out, err = capsys.readouterr()
    return dict(folder=folder, before=before, r=subprocess.CompletedProcess(args, e.value.code, out, err))


@pytest.mark.parametrize(("cid", "names"), [(c[0], c[3]) for c in CASES], ids=[c[0] for c in CASES])
def test_bad_option_is_one_line(request, tmp_path, shot_bytes, cache, monkeypatch, capsys, cid, names):
    args, env = next((c[1], c[2]) for c in CASES if c[0] == cid)
    if env:
        res = request.getfixturevalue("results")[cid]
    else:
        res = run_in_process(tmp_path / "case", shot_bytes, cache, args, monkeypatch, capsys)
    r = res["r"]
    lines = r.stderr.splitlines()
    assert r.returncode == 2, r.stderr
    assert r.stdout == ""
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("tween: error: "), lines[0]
    assert names in lines[0], lines[0]
    assert "secret" not in r.stderr
    assert listing(res["folder"]) == res["before"]
    assert (res["folder"] / "s.usda").read_bytes() == shot_bytes
    if env:
        # an unreachable broker is reported within seconds, not after minutes of retries (four
        # cases run at once here, beside the other test processes: 20 s was too tight under load)
        assert res["took"] < 45, res["took"]


def test_help_still_works(tmp_path):
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "fill", "--help"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=60)  # fmt: skip
    assert r.returncode == 0 and "--takes" in r.stdout and r.stderr == ""
    r = subprocess.run([sys.executable, "-m", "pipeline.cli"], cwd=tmp_path, capture_output=True, text=True,
                       timeout=60)  # fmt: skip
    assert r.returncode == 2 and "fill" in r.stdout and "review" in r.stdout
    assert listing(tmp_path) == []


def test_fill_options_check():
    from pipeline.errors import TweenError
    from pipeline.fill.api import MAX_DNA_POSES, MAX_SEED, MAX_TAKES, FillOptions
    from pipeline.infer.dna_poses import MAX_POSES

    assert MAX_DNA_POSES == MAX_POSES

    FillOptions(takes=MAX_TAKES, seed=MAX_SEED - MAX_TAKES + 1, fmt="usdc", dna_poses=8).check()
    for bad, opt in [
        (dict(takes=0), "--takes"),
        (dict(takes=MAX_TAKES + 1), "--takes"),
        (dict(takes=True), "--takes"),
        (dict(seed=-1), "--seed"),
        (dict(seed=MAX_SEED, takes=2), "--seed"),
        (dict(seed=1.5), "--seed"),
        (dict(fmt="abc"), "--format"),
        (dict(dna_poses=0), "--dna-poses"),
        (dict(keys="1001,nan"), "--keys"),
        (dict(range="1001-inf"), "--range"),
        (dict(model=""), "--model"),
        (dict(out_dir=""), "--out-dir"),
        (dict(library="lib", model="interpolation"), "--model interpolation is no network"),
    ]:
        with pytest.raises(TweenError, match=opt):
            FillOptions(**bad).check()


def test_redact_url():
    from workers.settings import redact_url

    assert redact_url("redis://:secret@127.0.0.1:1/0") == REDIS_SHOWN
    assert redact_url("amqp://guest:secret@127.0.0.1:1//") == AMQP_SHOWN
    assert redact_url("redis://127.0.0.1:6379/0") == "redis://127.0.0.1:6379/0"
    assert redact_url("sentinel://:a@h1:26379;sentinel://:b@h2:26379") == (
        "sentinel://:***@h1:26379;sentinel://:***@h2:26379"
    )
    assert redact_url("redis://h:6379/0?password=pw&db=1") == "redis://h:6379/0?password=***&db=1"


def test_shot_fixture_is_valid(tmp_path, shot_bytes):
    """The cases fail on their options, not on the shot: the same shot opens and plans."""
    from pipeline.fill.plan import make_plan

    shot = tmp_path / "s.usda"
    shot.write_bytes(shot_bytes)
    assert make_plan(str(shot), None, None, None, 30.0, own_rig=True).chars
