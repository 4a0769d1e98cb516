"""`tween bench` and `tween bench-farm` refuse what they cannot run before any work: one
``tween: error:`` line naming the option, file or variable, exit 2, nothing written. Every
bench's work is replaced by a failure here, so a refusal that came after it fails at once."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from cli_contract import refused

from pipeline.errors import TweenError


def _no_work(*a, **kw):
    raise AssertionError("the bench started its work before refusing")


@pytest.fixture
def no_work(monkeypatch):
    """No bench can run: each one's entry point fails the test."""
    import pipeline.bench.cli as cli
    import pipeline.bench.long_gaps as long_gaps
    import pipeline.bench.rig_variants as rig_variants
    import pipeline.bench.run as run
    import pipeline.bench.speed as speed

    monkeypatch.setattr(run, "run_bench", _no_work)
    monkeypatch.setattr(run, "test_windows", _no_work)
    monkeypatch.setattr(long_gaps, "run_long_gap_bench", _no_work)
    monkeypatch.setattr(rig_variants, "run_rig_bench", _no_work)
    monkeypatch.setattr(cli, "run_speed", _no_work)
    monkeypatch.setattr(speed, "sgemm_peak", _no_work)
    monkeypatch.setattr(cli, "_partial_keys_bench", _no_work)


def _rig_model(folder: Path) -> Path:
    folder.mkdir()
    (folder / "rig.json").write_text(json.dumps({"kind": "rig-ganimator-onnx", "name": "elephant"}))
    return folder


def test_bench_refuses_a_per_rig_model_folder(tmp_path, capsys, no_work):
    rig = _rig_model(tmp_path / "elephant")
    for extra in ([], ["--speed"], ["--long-gaps"]):
        line = refused(["bench", *extra, "--methods", rig, "--out", tmp_path / "out"], capsys, tmp_path)
        assert "--methods" in line and str(rig) in line and "per-rig model" in line, line
    assert not (tmp_path / "out").exists()


MODES = ([], ["--rig-variants", "--methods", "interp"], ["--speed"], ["--long-gaps"], ["--partial-keys"])


@pytest.mark.parametrize("mode", MODES, ids=lambda m: m[0] if m else "protocol")
def test_bench_refuses_an_out_it_cannot_write_before_any_work(tmp_path, capsys, no_work, mode):
    (tmp_path / "c.npz").write_bytes(b"x")
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        for out, says in (
            (tmp_path / "c.npz", "is a file, not a folder"),
            (tmp_path / "c.npz" / "sub", "is a file, not a folder"),
            (locked / "bench", "read-only"),
        ):
            line = refused(["bench", *mode, "--out", out], capsys, tmp_path)
            assert line.startswith(f"tween: error: --out {out}: ") and says in line, line
    finally:
        locked.chmod(0o755)


def test_bench_farm_refuses_its_out_and_shot_before_any_work(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("TWEEN_FARM_CONFIG", os.devnull)
    monkeypatch.delenv("TWEEN_BROKER_URL", raising=False)  # the farm bench would refuse that later
    (tmp_path / "somedir").mkdir()
    (tmp_path / "c.npz").write_bytes(b"x")
    line = refused(["bench-farm", "--out", tmp_path / "somedir"], capsys, tmp_path)
    assert f"--out {tmp_path / 'somedir'}: is a folder" in line, line
    line = refused(["bench-farm", "--out", tmp_path / "c.npz" / "farm.json"], capsys, tmp_path)
    assert "--out" in line and "is a file, not a folder" in line, line
    # The user's file is named, not the copy the bench would fill.
    out = tmp_path / "farm.json"
    line = refused(["bench-farm", "--shot", tmp_path / "c.npz", "--out", out], capsys, tmp_path)
    assert f"--shot {tmp_path / 'c.npz'}: not a USD shot" in line, line
    line = refused(["bench-farm", "--shot", tmp_path / "none.usda", "--out", out], capsys, tmp_path)
    assert f"--shot {tmp_path / 'none.usda'}: no such file" in line, line


def test_bench_farm_checks_the_users_shot_itself(tmp_path):
    from workers.bench import _validate_shot

    bad = tmp_path / "bad.usda"
    bad.write_text("#usda 1.0\nnot usd at all (\n")
    with pytest.raises(TweenError) as e:
        _validate_shot(bad, tmp_path / "work")
    assert str(bad) in str(e.value) and "sh000" not in str(e.value)
    assert not (tmp_path / "work").exists()


def test_bench_farm_finds_the_example_shot_from_any_folder(tmp_path, monkeypatch):
    from workers.bench import _default_shot

    monkeypatch.chdir(tmp_path)
    shot = _default_shot()
    assert shot.is_file() and shot.is_absolute() and shot.parent.name == "examples"


@pytest.mark.parametrize(
    "var, value",
    [
        ("TWEEN_SPEED_FRAMES", "abc"),
        ("TWEEN_SPEED_FRAMES", "0"),
        ("TWEEN_SPEED_FRAMES", "-5"),
        ("TWEEN_SPEED_REPEATS", "0"),
        ("TWEEN_SPEED_REPEATS", "x"),
    ],
)
def test_speed_refuses_bad_environment_variables(tmp_path, capsys, no_work, monkeypatch, var, value):
    monkeypatch.setenv(var, value)
    line = refused(["bench", "--speed", "--out", tmp_path / "out"], capsys, tmp_path)
    assert f"{var}={value!r}: must be a whole number" in line, line


@pytest.mark.parametrize(
    "text, says",
    [
        ("{", "not valid JSON"),
        ('{"kind": "generator-onnx"}', "missing key"),
        ("[1, 2]", "expected a JSON object"),
        ('{"kind": "generator-onnx", "files": 3}', "model.json"),
    ],
)
def test_speed_refuses_a_damaged_model_json_in_one_line(tmp_path, capsys, no_work, text, says):
    model = tmp_path / "m"
    model.mkdir()
    (model / "model.json").write_text(text)
    line = refused(["bench", "--speed", "--methods", model, "--out", tmp_path / "out"], capsys, tmp_path)
    assert str(model / "model.json") in line and says in line, line


@pytest.mark.parametrize(
    "methods, says",
    [
        ("spline", "--methods spline: --speed times a human network model's fill and spline has no network"),
        ("interp", "interp has no network"),
        ("zero", "zero has no network"),
        ("model,interp", "--speed times one model"),
    ],
)
def test_speed_says_why_a_method_cannot_be_timed(tmp_path, capsys, no_work, methods, says):
    line = refused(["bench", "--speed", "--methods", methods, "--out", tmp_path / "out"], capsys, tmp_path)
    assert says in line and "not found" not in line, line


@pytest.mark.parametrize(
    "args, names",
    [
        (
            ["--long-gaps", "--source", "cmu:5", "--posture", "30", "--mirrored"],
            "--mirrored, --posture, --source",
        ),
        (["--rig-variants", "--methods", "interp", "--source", "cmu"], "--source"),
        (["--rig-variants", "--methods", "interp", "--mirrored"], "--mirrored"),
        (["--speed", "--limit", "3"], "--limit"),
        (["--speed", "--posture", "10"], "--posture"),
        (["--partial-keys", "--keys-every", "5"], "--keys-every"),
        (["--keys-every", "5"], "--keys-every"),
        (["--long-gaps", "--keys-every", "5"], "--keys-every"),
        (["--speed", "--long-gaps"], "--long-gaps and --speed"),
        (["--rig-variants", "--partial-keys"], "--partial-keys and --rig-variants"),
    ],
)
def test_bench_refuses_options_its_kind_of_bench_does_not_use(tmp_path, capsys, no_work, args, names):
    line = refused(["bench", *args, "--out", tmp_path / "out"], capsys, tmp_path)
    assert line.startswith(f"tween: error: {names}: "), line


def test_limit_applies_to_the_cmu_takes(tmp_path, monkeypatch):
    import pipeline.bench.heldout as heldout

    takes = [tmp_path / f"005_{i:02d}.bvh.gz" for i in range(1, 21)]
    monkeypatch.setattr(heldout, "cmu_files", lambda subjects=None: takes)
    monkeypatch.setattr(heldout, "cache_dir", lambda: tmp_path)
    # The windows of the first take only, as a cached run left them.
    np.savez(
        tmp_path / f"cmu-windows-v{heldout.VERSION}-1-s5.npz", rots=np.zeros((4, 1)), roots=np.zeros((4, 1))
    )
    rots, _ = heldout.cmu_windows((5,), limit=1)
    assert len(rots) == 4


def test_bench_records_and_describes_the_windows_it_ran_on(tmp_path, monkeypatch):
    import pipeline.bench.run as run

    seen = {}

    def windows(limit, mirrored, posture, source):
        seen["limit"] = limit
        return np.zeros((3, 65, 1, 4)), np.zeros((3, 65, 3))

    fake = {t: {m: 1.0 for m in run.METRICS} | {"skate_gt": 0.0} for t in run.TRANSITIONS}
    monkeypatch.setattr(run, "test_windows", windows)
    monkeypatch.setattr(run, "load_split", lambda name: None)
    monkeypatch.setattr(run, "position_stats", lambda train: (None, None))
    monkeypatch.setattr(run, "evaluate", lambda *a: fake)
    res = run.run_bench(["zero"], 1, tmp_path / "out", source="cmu:5")
    data = json.loads((tmp_path / "out" / "bench.json").read_text())
    assert seen["limit"] == 1 and data["cmu_takes_limit"] == 1 and data["eval_clips_limit"] is None
    first = res["markdown"].splitlines()[0]
    assert (
        first.startswith("Windows: 3 (CMU takes of subjects 5, first 1 take(s)") and "eval split" not in first
    )
    res = run.run_bench(["zero"], 2, tmp_path / "out", source="eval")
    data = json.loads((tmp_path / "out" / "bench.json").read_text())
    assert data["eval_clips_limit"] == 2 and data["cmu_takes_limit"] is None
    assert res["markdown"].startswith(
        "Windows: 3 (eval split, first 2 clip(s), 65 frames every 40, PROTOCOL.md)"
    )


@pytest.mark.parametrize("mode", MODES, ids=lambda m: m[0] if m else "protocol")
def test_bench_refuses_to_replace_an_earlier_runs_results_without_force(tmp_path, capsys, no_work, mode):
    """Nothing a user has is replaced without --force: a rerun overwrote the results before."""
    from pipeline.bench.cli import _check_mode
    from pipeline.bench.outputs import OUTPUTS

    kind = _check_mode({}, {m: m in mode for m in OUTPUTS if m})
    out = tmp_path / "out"
    out.mkdir()
    earlier = out / OUTPUTS[kind][-1]
    earlier.write_text("an earlier run's")
    line = refused(["bench", *mode, "--out", out], capsys, tmp_path)
    assert (
        line
        == f"tween: error: {earlier}: --out holds an earlier run's results; give --force to replace them, or another folder"
    )
    with pytest.raises(AssertionError, match="started its work"):  # --force: past every check
        refused(["bench", *mode, "--out", out, "--force"], capsys, tmp_path)
    assert earlier.read_text() == "an earlier run's"
