"""The blocking bench (pipeline/bench/blocking.py): the trusted fill on shots keyed every N frames."""

import json

import pytest

from pipeline.bench import blocking
from pipeline.errors import TweenError


def test_blocking_bench_runs_end_to_end_on_cmu_takes(tmp_path, capsys):
    assert blocking.main(["--sources", "cmu", "--every", "10", "--limit", "2", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "blocking.json").read_text())
    r = report["sources"]["cmu"]["results"]["10"]
    assert report["sources"]["cmu"]["shots"] >= 1 and r["probes"] >= 1
    for k in ("model", "spline", "decided"):
        assert r[k] > 0
    # The decided fill is a blend of the two, so it cannot be worse than the worse of them by much.
    assert r["decided"] <= 1.05 * max(r["model"], r["spline"])
    assert 0.0 <= r["mean_weight"] <= 1.0
    assert "| cmu | 10 |" in capsys.readouterr().out


def test_too_short_clips_are_one_clear_error():
    with pytest.raises(TweenError, match="no clip longer than 181 frames"):
        blocking.shots("eval", limit=3)
