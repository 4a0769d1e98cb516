"""`tween bench --methods`: every method's model folder is loaded, and a damaged one refused,
before the bench reads its data (it was refused after the windows were read and the methods
before it had run: 19 s, 32 s with --source cmu)."""

from __future__ import annotations

import pytest

import pipeline.bench.run as bench_run
from pipeline.errors import TweenError


def test_damaged_model_folder_is_refused_before_the_data_is_read(tmp_path, monkeypatch):
    mdl = tmp_path / "mdl"
    mdl.mkdir()
    (mdl / "model.json").write_text("")

    def no_data(*a, **k):
        raise AssertionError("the bench read its data before loading every method")

    monkeypatch.setattr(bench_run, "load_split", no_data)
    monkeypatch.setattr(bench_run, "test_windows", no_data)
    with pytest.raises(TweenError, match=r"model\.json"):
        bench_run.run_bench(["zero", "interp", "spline", str(mdl)], 1, tmp_path / "out")
    assert not (tmp_path / "out").exists()
