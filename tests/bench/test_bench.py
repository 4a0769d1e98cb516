"""`tween bench` end to end on a few eval clips."""

import json
import subprocess
import sys

import numpy as np

from pipeline.bench.methods import inbetweener_method, resolve
from pipeline.infer.spline import SplineInbetweener


def test_bench_cli_writes_json_and_table(tmp_path):
    out = tmp_path / "bench"
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "pipeline.cli",
            "bench",
            "--methods",
            "zero,interp,spline",
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
    assert "| spline |" in res.stdout and "| spline ÷ interp |" in res.stdout
    data = json.loads((out / "bench.json").read_text())
    r = data["results"]
    assert data["windows"] > 0
    for t in ("5", "15", "30", "45"):
        # Interpolation beats holding the last frame, and errors grow with the gap.
        assert r["interp"][t]["L2P"] < r["zero"][t]["L2P"]
        assert r["interp"][t]["MPJPE"] <= r["zero"][t]["MPJPE"]
        assert r["spline"][t]["L2P"] < r["zero"][t]["L2P"]
    # Through the context frames, the spline follows their motion at short gaps.
    assert r["spline"]["5"]["L2P"] < r["interp"]["5"]["L2P"]
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


def test_a_source_naming_no_takes_is_refused_before_any_data_is_read(tmp_path):
    """cmu:99 was said after the train statistics were read, below a progress line."""
    res = subprocess.run([sys.executable, "-m", "pipeline.cli", "bench", "--methods", "interp", "--source", "cmu:99",
                          "--out", str(tmp_path / "b")], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert res.stderr.startswith("tween: error: ") and "no CMU takes of subjects 99" in res.stderr


def test_spline_bench_method_is_the_product_spline_through_context_and_target():
    rng = np.random.default_rng(0)
    n, c, J, T = 3, 10, 21, 30
    rot = rng.normal(size=(n, c + T + 1, J, 4))
    rot = (rot / np.linalg.norm(rot, axis=-1, keepdims=True)).astype(np.float32)
    root = rng.normal(size=(n, c + T + 1, 3)).astype(np.float32)
    args = (rot[:, :c], root[:, :c], rot[:, -1], root[:, -1], T)
    r, p = resolve("spline")(*args)
    r_ref, p_ref = inbetweener_method(SplineInbetweener())(*args)
    assert r.shape == (n, T, J, 4) and p.shape == (n, T, 3)
    np.testing.assert_allclose(r, r_ref, atol=1e-6)
    np.testing.assert_allclose(p, p_ref, atol=1e-5)
    # Not the two-key interpolation: the context frames bend the curve.
    r2, p2 = resolve("interp")(*args)
    assert np.abs(p - p2).max() > 0.1
