"""Recipes as files (recipes/*.toml, `tween train --recipe`) and `tween train`'s flags made
from TrainConfig: one declaration per knob."""

import json
import subprocess
import sys
from dataclasses import fields
from pathlib import Path

import pytest

pytest.importorskip("torch")

from typer.testing import CliRunner  # noqa: E402

from pipeline.cli import app  # noqa: E402
from pipeline.train.recipe import (  # noqa: E402
    RECIPES,
    RecipeError,
    check_recipe,
    configs,
    load_recipe,
    parse_train_args,
    train_command,
    train_flags,
)

ROOT = Path(__file__).resolve().parents[2]
RECIPE_NAMES = sorted(p.stem for p in RECIPES.glob("*.toml"))
# A recipe naming no `model` is an experiment's runs (no shipped folder to match).
SHIPPED = [n for n in RECIPE_NAMES if load_recipe(n).model]


def _tween(*args, env=None):
    return CliRunner().invoke(app, list(args), env=env, catch_exceptions=False)


def test_every_shipped_model_has_a_recipe():
    assert SHIPPED == [
        "tween-bandai-delta-v3",
        "tween-bandai-dna-v1",
        "tween-bandai-v5.3",
        "tween-cmu-s123-delta-ft",
    ]
    for name in SHIPPED:
        rec = load_recipe(name)
        assert (ROOT / rec.model / "model.json").exists()
        meta = json.loads((ROOT / rec.model / "model.json").read_text())
        assert meta["name"] == rec.name
        assert f"--name {rec.name}" in " ".join(rec.export.args)


@pytest.mark.parametrize("name", SHIPPED)
def test_recipe_parses_and_every_stage_is_valid_cli(name):
    rec = load_recipe(name)
    parsed = check_recipe(rec)  # every stage's args through `tween train`'s own parser
    assert len(parsed) == len(rec.stages)
    for s, (cfg, _) in zip(rec.stages, parsed, strict=True):
        assert cfg.device == "cpu"  # replays run on CPU unless told otherwise
        assert s.wall_s and s.wall_s > 0 and s.measured
        if s.init:  # an earlier stage's checkpoint, or a model folder as it is
            want = s.init if "/" in s.init else f"runs/{rec.name}/{s.init}/generator.pt"
            assert cfg.init == want
    # The export's inference settings are those the shipped model.json holds.
    meta = json.loads((ROOT / rec.model / "model.json").read_text())
    from pipeline.train.commands import export_command

    ctx = export_command().make_context("export", ["run", "--out", "x", *rec.export.args])
    for key in ("root", "pad", "pad_tail", "min_window", "feet_anchor", "feet_orient"):
        assert ctx.params[key] == meta[key], key
    # Stages after the first three agree with model.json's record of them (steps, batch, seed,
    # LSGAN start, gap weighting, measured seconds); stages 1-3 sum to its 6,324 s.
    cfgs = {s.name: c for s, (c, _) in zip(rec.stages, parsed, strict=True)}
    walls = {s.name: s.wall_s for s in rec.stages}
    if "stages" not in meta:  # a one-stage model (a fine-tune): its own steps and seconds
        last = rec.stages[-1].name
        assert cfgs[last].steps == meta["train_steps"] and walls[last] == meta["train_seconds"]
        return
    assert walls["s1"] + walls["s2"] + walls["s3"] == meta["stages"][0]["seconds"]
    for st in meta["stages"][1:]:
        n = st["stage"] if isinstance(st["stage"], int) else None
        key = f"s{n}" if n else rec.stages[-1].name
        c = cfgs[key]
        assert (c.steps, c.batch, c.seed, c.adv_start) == (
            st["steps"],
            st["batch"],
            st["seed"],
            st["adv_start"],
        )
        assert c.gap_weighting == st.get("gap_weighting", 1.0)
        assert walls[key] == st["seconds"]


@pytest.mark.parametrize("name", sorted(set(RECIPE_NAMES) - set(SHIPPED)))
def test_an_experiment_recipe_parses_and_records_its_runs(name):
    rec = load_recipe(name)
    parsed = check_recipe(rec)
    assert rec.stages and len(parsed) == len(rec.stages)
    for s, (cfg, _) in zip(rec.stages, parsed, strict=True):
        assert cfg.device == "cpu" and s.wall_s and s.wall_s > 0 and s.measured, s.name


def test_a_typo_in_a_recipe_fails(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "bad"\n[[stage]]\nname = "a"\nargs = "--stpes 3"\n')
    with pytest.raises(RecipeError, match="--stpes"):
        check_recipe(load_recipe(bad))
    bad.write_text('name = "bad"\n[[stage]]\nname = "a"\nargs = "--partial-layout sideways"\n')
    with pytest.raises(RecipeError, match="partial-layout"):
        check_recipe(load_recipe(bad))
    bad.write_text('name = "bad"\n[[stage]]\nname = "b"\ninit = "a"\nargs = ""\n')
    with pytest.raises(RecipeError, match="no earlier stage"):
        load_recipe(bad)
    bad.write_text('name = "bad"\n[[stage]]\nname = "a"\nargs = "--init x.pt"\n')
    with pytest.raises(RecipeError, match="--init"):
        load_recipe(bad)
    bad.write_text('name = "bad"\n[[stage]]\nname = "a"\nargz = ""\n')
    with pytest.raises(RecipeError, match="argz"):
        load_recipe(bad)


def test_dry_run_prints_the_stages_in_order_with_their_inits(tmp_path):
    out = tmp_path / "v53"
    res = _tween("train", "--recipe", "tween-bandai-v5.3", "--out", str(out), "--dry-run")
    assert res.exit_code == 0, res.output
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith("tween ")]
    assert [ln.split()[3] for ln in lines[:-1]] == [str(out / f"s{i}") for i in range(1, 10)]
    for i, ln in enumerate(lines[1:-1], start=2):
        assert f"--init {out / f's{i - 1}' / 'generator.pt'}" in ln
    assert "--init" not in lines[0] and "--path-steps 2000" in lines[0]
    assert "--data-pack" in lines[3] and "--device" not in res.stdout  # CPU by default
    assert lines[-1].startswith(f"tween export {out / 's9'} --out {out / 'model'} --name tween-bandai-v5.3")
    assert "--pad hold-key --pad-tail 16 --min-window 64 --feet-anchor" in lines[-1]
    assert "4.73 h (17,012.5 s) on cpu + 20.6 min (1,236.1 s) on cuda" in res.stdout
    assert not out.exists()  # nothing trained
    # Flags beside --recipe apply to every stage; --from-stage starts later.
    res = _tween("train", "--recipe", "tween-bandai-dna-v1", "--out", str(out), "--dry-run", "--device",
                 "cuda", "--workers", "7", "--from-stage", "dna")  # fmt: skip
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith("tween ")]
    assert len(lines) == 2 and lines[0].split()[3] == str(out / "dna")
    assert f"--init {out / 's7' / 'generator.pt'}" in lines[0] and "--device cuda --workers 7" in lines[0]


def test_tiny_recipe_runs_inits_and_resumes(tmp_path):
    import torch

    recipe = tmp_path / "tiny.toml"
    recipe.write_text(
        'name = "tiny"\n'
        '[[stage]]\nname = "one"\nargs = "--path-steps 2 --steps 5 --batch 4 --lengths 64 --seed 1"\n'
        "wall_s = 1.0\n"
        '[[stage]]\nname = "two"\ninit = "one"\n'
        'args = "--path-steps 0 --steps 4 --batch 4 --lengths 64 --lr 3e-4 --adv-start 2 --seed 2"\n'
        '[export]\nstage = "two"\npath_from = "one"\nargs = "--name tiny --pad-tail 16"\n'
    )
    out = tmp_path / "runs"
    res = _tween("train", "--recipe", str(recipe), "--out", str(out), "--limit-clips", "2")
    assert res.exit_code == 0, res.output
    one, two = (torch.load(out / s / "generator.pt", weights_only=False) for s in ("one", "two"))
    assert one["step"] == 5 and two["step"] == 4
    assert two["config"]["init"] == str(out / "one" / "generator.pt")  # stage two continued one
    assert two["config"]["limit_clips"] == 2 and two["config"]["adv_start"] == 2 and "disc" in two
    assert (out / "one" / "path.pt").exists() and not (out / "two" / "path_log.jsonl").exists()
    assert json.loads((out / "model" / "model.json").read_text())["name"] == "tiny"
    assert (out / "two" / "path.pt").exists()  # the export's path predictor, from stage one
    stamps = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}
    res = _tween("train", "--recipe", str(recipe), "--out", str(out), "--limit-clips", "2")
    assert res.exit_code == 0, res.output
    assert res.stderr.count("skipped") == 3  # both stages and the export
    assert stamps == {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}


def test_help_lists_every_trainconfig_field_with_its_help():
    from pipeline.train.generator_training import TrainConfig

    res = _tween("train", "--help", env={"COLUMNS": "400"})
    assert res.exit_code == 0
    text = " ".join(res.stdout.replace("│", " ").split())
    names = [f.name for f in fields(TrainConfig) if f.name != "model"]
    names += list(next(f for f in fields(TrainConfig) if f.name == "model").metadata["flags"])
    opts = {p.name: p for p in train_command().params}
    for name in names:
        meta = {f.name: f.metadata for f in fields(TrainConfig)}.get(name)
        flag = "--" + name.replace("_", "-")
        assert flag in text, flag
        assert opts[name].help and " ".join(opts[name].help.split()) in text, flag
        if meta is not None:
            assert opts[name].help == meta["help"]
    assert {fl.name for fl in train_flags()} == set(names)
    for extra in ("--out", "--path-steps", "--recipe", "--from-stage", "--dry-run"):
        assert extra in text


def test_cli_defaults_are_trainconfig_defaults():
    from pipeline.train.generator_training import TrainConfig
    from pipeline.train.path_training import PathTrainConfig

    cfg, path_cfg = configs(parse_train_args([]))
    assert cfg == TrainConfig()
    assert path_cfg.steps == PathTrainConfig().steps
    # The values the card's commands relied on (the CLI's, where the two used to differ).
    assert (cfg.steps, cfg.adv_start, cfg.lengths, cfg.lr, path_cfg.steps) == (
        8000,
        6800,
        (64, 96, 128),
        1e-3,
        2000,
    )
    assert configs(parse_train_args(["--adv-start", "-1"]))[0].adv_start is None
    assert configs(parse_train_args(["--steps", "100"]))[0].adv_start is None  # starts after the end
    got = configs(parse_train_args(["--key-adapter", "--dna", "8"]))[0]
    assert got.model.key_adapter and got.model.dna == 8


def test_tween_help_does_not_import_torch():
    code = "import sys, pipeline.cli; assert 'torch' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


def test_the_card_gives_the_recipe_and_its_summed_wall_time():
    card = (ROOT / "models/default/MODEL_CARD.md").read_text()
    assert len(card.splitlines()) <= 200
    assert "tween train --recipe tween-bandai-v5.3" in card and "(HISTORY.md)" in card
    walls = load_recipe("tween-bandai-v5.3").wall_s()
    assert f"{walls['cpu']:,.1f} s" in card and f"{walls['cpu'] / 3600:.2f} h" in card
    assert f"{walls['cuda']:,.1f} s" in card and f"{walls['cuda'] / 60:.1f} min" in card
    assert "tween train --recipe tween-bandai-dna-v1" in (ROOT / "models/dna/MODEL_CARD.md").read_text()


def test_the_delta_model_ships_the_checkpoint_its_next_stage_resumes_from():
    """models/delta/torch/generator.pt is the exported network's own checkpoint (its last
    stage), so a stage with ``init = "models/delta"`` continues it in a fresh clone."""
    import torch

    from pipeline.train.export import verify
    from pipeline.train.generator_training import init_checkpoint

    folder = ROOT / "models/delta"
    ckpt = init_checkpoint(str(folder))
    assert ckpt == folder / "torch" / "generator.pt"
    state = torch.load(ckpt, weights_only=False, map_location="cpu")
    meta = json.loads((folder / "model.json").read_text())
    rec = load_recipe("tween-bandai-delta-v3")
    assert state["config"]["model"]["delta"] and meta["generator"]["delta"]
    assert (
        state["step"]
        == meta["train_steps"]
        == configs(parse_train_args(rec.stage(rec.export.stage).args))[0].steps
    )
    assert verify(ckpt.parent, folder) < 1e-4  # the ONNX file is this checkpoint's export


def test_exported_checkpoints_name_repository_paths_relative_to_it(tmp_path):
    """A shipped model's torch checkpoint does not carry the exporting machine's paths: its
    config's paths inside the repository (a recipe resolves ``init`` and ``corpus``) are
    written relative to it; a studio's takes elsewhere stay as the run recorded them."""
    import torch

    from pipeline.train.export import _shipped

    state = {"model": {}, "step": 3, "optimiser": {}, "config": {
        "init": str(ROOT / "models/delta"), "corpus": str(ROOT / "pipeline/data/corpora/bandai-cmu123.toml"),
        "data": str(tmp_path / "takes"), "steps": 3}}  # fmt: skip
    out = _shipped(state, ("model", "config", "step"))
    assert "optimiser" not in out and out["step"] == 3
    assert out["config"] == {"init": "models/delta", "corpus": "pipeline/data/corpora/bandai-cmu123.toml",
                             "data": str(tmp_path / "takes"), "steps": 3}  # fmt: skip
    for ckpt in sorted(ROOT.glob("models/*/torch/*.pt")):
        config = torch.load(ckpt, weights_only=False, map_location="cpu")["config"]
        absolute = {k: v for k, v in config.items() if isinstance(v, str) and v.startswith("/")}
        assert not absolute, f"{ckpt}: {absolute}"


def test_saved_configs_drop_retired_switches_and_refuse_other_values():
    """A checkpoint's network config (or model.json's "generator") may still carry the
    switches of retired experiments, at the value every shipped model has; another value
    names the switch, since no release runs it."""
    pytest.importorskip("torch")
    from pipeline.infer.folder import RETIRED, ModelFolderError
    from pipeline.networks.generator import GeneratorConfig

    saved = {"width": 48, "levels": [48, 64], "key_adapter": True, **RETIRED, "extra": {}}
    cfg = GeneratorConfig.saved(saved)
    assert cfg.levels == (48, 64) and cfg.key_adapter and not hasattr(cfg, "residual")
    for key, other in (("residual", False), ("tta", False), ("key_mask", True), ("rotation", "euler")):
        with pytest.raises(ModelFolderError, match=f"generator.{key}.*runs"):
            GeneratorConfig.saved({**saved, key: other}, "run/generator.pt")
