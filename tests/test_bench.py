"""`tween bench` end to end on a few eval clips."""

import json
import subprocess
import sys


def test_bench_cli_writes_json_and_table(tmp_path):
    out = tmp_path / "bench"
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "pipeline.cli",
            "bench",
            "--methods",
            "zero,interp",
            "--limit",
            "25",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    assert "**L2P**" in res.stdout and "| interp |" in res.stdout
    data = json.loads((out / "bench.json").read_text())
    r = data["results"]
    assert data["windows"] > 0
    for t in ("5", "15", "30", "45"):
        # Interpolation beats holding the last frame, and errors grow with the gap.
        assert r["interp"][t]["L2P"] < r["zero"][t]["L2P"]
        assert r["interp"][t]["MPJPE"] <= r["zero"][t]["MPJPE"]
    assert r["zero"]["5"]["L2P"] < r["zero"]["45"]["L2P"]
    assert r["zero"]["5"]["skate"] == 0  # holding still never slides


def test_bench_with_too_few_clips_for_a_window_is_a_one_line_error(tmp_path):
    out = tmp_path / "bench"
    cmd = [sys.executable, "-m", "pipeline.cli", "bench", "--methods", "interp", "--limit", "1"]
    for extra in ([], ["--partial-keys"]):
        res = subprocess.run([*cmd, *extra, "--out", str(out)], capture_output=True, text=True, timeout=300)
        assert res.returncode == 2, res.stderr
        error = [line for line in res.stderr.splitlines() if line.startswith("tween: error:")]
        assert len(error) == 1 and "eval split: no 65-frame window" in error[0] and "--limit" in error[0]
        assert "Traceback" not in res.stderr and not out.exists()
