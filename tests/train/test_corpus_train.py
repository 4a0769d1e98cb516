"""`tween train --corpus FILE` (issue 30, item 1): a corpus of two rigs prepared on the way
and trained on; what its export would record as the model's terms."""

from __future__ import annotations

import shutil

import pytest

CMU = "002_02.bvh.gz"


def test_train_on_a_corpus_of_two_rigs_and_its_terms(data_dir, bandai_clip, tmp_path, monkeypatch):
    torch = pytest.importorskip("torch")
    from typer.testing import CliRunner

    from pipeline.cli import app
    from pipeline.train.export import data_terms

    monkeypatch.setenv("TWEEN_CACHE", str(tmp_path / "cache"))
    (tmp_path / "bandai").mkdir()
    shutil.copy(bandai_clip, tmp_path / "bandai" / bandai_clip.name)
    (tmp_path / "studio").mkdir()
    shutil.copy(data_dir / "cmu_iclone" / CMU, tmp_path / "studio" / CMU)
    desc = tmp_path / "corpus.toml"
    desc.write_text('name = "two"\n[[source]]\nname = "bandai"\npath = "bandai"\nlicence = "CC BY-NC 4.0"\n'
                    '[[source]]\nname = "studio"\npath = "studio"\nlicence = "CC0"\nweight = 2\n')  # fmt: skip
    out = tmp_path / "run"
    opts = ["--path-steps", "2", "--steps", "4", "--batch", "4", "--lengths", "64", "--adv-start", "-1"]
    res = CliRunner().invoke(
        app, ["train", "--corpus", str(desc), *opts, "--out", str(out)], catch_exceptions=False
    )
    assert res.exit_code == 0, res.output
    assert [p.name for p in (tmp_path / "cache" / "corpora").iterdir()][0].startswith(
        "corpus-"
    )  # prepared once
    run = torch.load(out / "generator.pt", weights_only=False)
    assert run["config"]["corpus"] == str(desc) and run["step"] == 4
    terms = data_terms(run["config"])
    assert terms["licence"] == "CC BY-NC 4.0; CC0"
    assert [(s["licence"], s["weight"]) for s in terms["sources"]] == [("CC BY-NC 4.0", 1.0), ("CC0", 2.0)]
    assert terms["commercial"] is False  # a non-commercial source among them
    assert data_terms({"corpus": str(tmp_path / "elsewhere.toml")}) == {}  # a host without it: a warning
    # A run on the train split states its CC BY-NC terms too (it stated none: "not stated" in fills).
    plain = data_terms({"steps": 4})
    assert plain["licence"] == "CC BY-NC 4.0" and plain["commercial"] is False
    assert plain["sources"][0]["name"].startswith("Bandai Namco Research Motion Dataset")
    # --corpus reads its own sources: with --data it is one line, nothing written.
    bad = CliRunner().invoke(app, ["train", "--corpus", str(desc), "--data", str(tmp_path), *opts, "--out",
                                   str(tmp_path / "r")])  # fmt: skip
    assert bad.exit_code == 2 and "drop --data" in bad.output and not (tmp_path / "r").exists()


def _stub_source(bandai_clip, folder):
    """``folder`` holding one 40-frame take: a corpus source too short for --lengths 64."""
    from pipeline.motion.bvh import read_bvh, write_bvh

    folder.mkdir()
    write_bvh(read_bvh(bandai_clip).slice(0, 40), folder / "stub.bvh")


def _refused_line(args, tmp_path) -> str:
    """`tween ARGS` in its own process (its own cache), refused: exit 2, nothing on stdout;
    its one error line."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "TWEEN_CACHE": str(tmp_path / "cache")}
    res = subprocess.run([sys.executable, "-m", "pipeline.cli", *map(str, args)], env=env, capture_output=True,
                         text=True, timeout=300)  # fmt: skip
    assert res.returncode == 2 and res.stdout == "", res.stderr
    (line,) = [x for x in res.stderr.splitlines() if x.startswith("tween: error:")]
    assert "path predictor" not in res.stderr, res.stderr  # refused before anything trained
    return line


def test_a_source_with_no_take_as_long_as_the_lengths_is_named_before_training(bandai_clip, tmp_path):
    """Its weight went to the other sources with nothing said (ClipSet.draw_p)."""
    pytest.importorskip("torch")
    (tmp_path / "long").mkdir()
    shutil.copy(bandai_clip, tmp_path / "long" / bandai_clip.name)
    _stub_source(bandai_clip, tmp_path / "short")
    desc = tmp_path / "corpus.toml"
    desc.write_text('name = "mixed"\n[[source]]\nname = "long"\npath = "long"\nlicence = "CC0"\n'
                    '[[source]]\nname = "stubs"\npath = "short"\nlicence = "CC0"\n')  # fmt: skip
    out = tmp_path / "run"
    line = _refused_line(["train", "--corpus", desc, "--path-steps", "2", "--steps", "4", "--batch", "4",
                          "--adv-start", "-1", "--lengths", "30,64", "--out", out], tmp_path)  # fmt: skip
    assert "source stubs: no take of 64 frames (at 30 fps) for --lengths 64; its longest is 40" in line, line
    assert not out.exists()


def test_a_recipe_stage_whose_corpus_is_too_short_is_named_before_the_first_stage_trains(
    bandai_clip, tmp_path
):
    """Stage one would have trained for its minutes before stage two's corpus was found wanting."""
    pytest.importorskip("torch")
    _stub_source(bandai_clip, tmp_path / "short")
    desc = tmp_path / "corpus.toml"
    desc.write_text('name = "stubs"\n[[source]]\nname = "stubs"\npath = "short"\nlicence = "CC0"\n')
    tiny = "--steps 4 --batch 2 --lengths 64 --adv-start -1 --path-steps 0"
    recipe = tmp_path / "two.toml"
    recipe.write_text(f'name = "two"\n[[stage]]\nname = "one"\nargs = "{tiny} --limit-clips 1"\n'
                      f'[[stage]]\nname = "later"\ninit = "one"\nargs = "{tiny} --corpus {desc}"\n')  # fmt: skip
    out = tmp_path / "runs"
    line = _refused_line(["train", "--recipe", recipe, "--out", out], tmp_path)
    assert f"{recipe}: stage 'later': " in line and "no take of 64 frames" in line, line
    assert not (out / "one").exists()  # stage one never started
