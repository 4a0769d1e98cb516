"""The library bench's splits: nothing scored is in the library, and ``others`` holds out
whole actors (CMU subjects 5-7) from a library of only what the default may train on."""

import pytest

from pipeline.bench import library as bench
from pipeline.data.split import list_clips
from pipeline.errors import TweenError


@pytest.mark.parametrize("source", ["cmu", "bandai", "others"])
def test_no_held_out_take_is_in_the_library(source, data_dir):
    lib, held = bench.split(source)
    assert lib and held and not set(lib) & set(held)


def test_others_holds_out_whole_actors_and_trains_on_none_of_them(data_dir):
    lib, held = bench.split("others")
    cmu = [f for f in lib if "cmu_iclone" in str(f)]
    assert {f.name[:3] for f in cmu} == {"001", "002", "003"}
    assert {f.name[:3] for f in held} == {"005", "006", "007"}
    # The rest is the Bandai train split: never the protocol's eval split.
    assert set(lib) - set(cmu) == set(list_clips("train"))
    assert not set(lib) & set(list_clips("eval"))


def test_others_has_no_tuning_split(data_dir, capsys):
    with pytest.raises(ValueError, match="no tuning split"):
        bench.split("others", tuning=True)
    # A refusal is a TweenError: one line, exit 2 under run_main (test_bench_entry_errors).
    with pytest.raises(TweenError, match="--tuning: others: no tuning split"):
        bench.main(["--source", "others", "--tuning"])
    with pytest.raises(TweenError, match="--source: one or more of .*others"):
        bench.main(["--source", "elsewhere"])


def test_model_is_the_network_of_every_method_but_the_spline(tmp_path):
    fills = bench.fills_for(tmp_path / "lib", "runs/studio/model")
    assert {m: f["model"] for m, f in fills.items()} == {
        "library": "runs/studio/model",
        "library-spline": "runs/studio/model",
        "library-alone": "runs/studio/model",
        "default": "runs/studio/model",
        "spline": "spline",
    }
    assert bench.fills_for(tmp_path / "lib")["library"]["model"] == "default"


def test_a_model_that_is_not_there_is_refused_before_anything_runs(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(bench, "run", lambda *a, **k: pytest.fail("ran with a missing --model"))
    with pytest.raises(TweenError, match="--model .*nowhere"):
        bench.main(["--source", "cmu", "--model", str(tmp_path / "nowhere"), "--out", str(tmp_path / "out")])
    assert not (tmp_path / "out").exists()


def test_the_report_names_a_network_other_than_the_default():
    rep = {"max_frames": 300, "methods": ["spline"], "sources": {}}
    assert "The network" not in bench.markdown(rep)
    assert "The network: runs/studio/model." in bench.markdown({**rep, "model": "runs/studio/model"})
