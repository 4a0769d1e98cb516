"""A recipe file that cannot be replayed as written is refused in one line naming the file
and the key, before anything runs, prints or is written (`tween train --recipe FILE`)."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("torch")

from cli_contract import refused, succeeded  # noqa: E402

from pipeline.train.recipe import RECIPES  # noqa: E402

STAGE = '[[stage]]\nname = "a"\nargs = "--steps 4 --path-steps 0 --batch 2 --lengths 64"\n'
TWO = STAGE + '[[stage]]\nname = "b"\ninit = "a"\nargs = "--steps 4 --path-steps 0 --batch 2 --lengths 64"\n'

# What the error line says -> the recipe's text (each file is the one the line names).
BAD = {
    "stage 'a': args must be a string of arguments": '[[stage]]\nname = "a"\nargs = 5\n',
    "stage 'a': args: no closing quotation": '[[stage]]\nname = "a"\nargs = "--steps 4 --data \'x"\n',
    "stage must be [[stage]] tables, not a string": 'stage = "abc"\n',
    "stage 1: must be a [[stage]] table, not an integer": "stage = [1]\n",
    ": name must be a string, not an integer": "name = 5\n" + STAGE,
    "stage 1: name must be a string, not an integer": '[[stage]]\nname = 5\nargs = "--steps 4"\n',
    "stage 1: no name = NAME": '[[stage]]\nargs = "--steps 4"\n',
    "stage 'b': init must be a string, not an integer": STAGE + '[[stage]]\nname = "b"\ninit = 3\n',
    "stage 'a': packed must be true or false, not a string": STAGE + 'packed = "yes"\n',
    "stage 'a': wall_s must be a number (seconds), not a string": STAGE + 'wall_s = "long"\n',
    "stage 'a': wall_s = -1: must be a number of seconds, 0 or more": STAGE + "wall_s = -1\n",
    "stage 'a': measured must be a string": STAGE + "measured = 2\n",
    "stage 'a': unknown keys ['export']": STAGE + "export = 1\n",
    "unknown keys ['stages']": 'stages = "a"\n' + STAGE,
    "base must be a table {recipe = NAME, through = STAGE}, not a string": 'base = "x"\n' + STAGE,
    "base: no recipe = NAME": 'base = {through = "s1"}\n' + STAGE,
    "base: unknown keys ['thru']": 'base = {recipe = "tween-bandai-v5.3", thru = "s1"}\n' + STAGE,
    "base: no recipe 'nope'": 'base = {recipe = "nope"}\n' + STAGE,
    "base: through = 'zz' is no stage of": 'base = {recipe = "tween-bandai-v5.3", through = "zz"}\n' + STAGE,
    "stage 's1' twice": 'base = {recipe = "tween-bandai-v5.3", through = "s2"}\n[[stage]]\nname = "s1"\n',
    "stage 'a' twice": STAGE + STAGE,
    "[export]: no stage = STAGE": STAGE + '[export]\nargs = "--name x"\n',
    "export must be an [export] table": 'export = "a"\n' + STAGE,
    "[export]: stage = 'zz' is no stage": STAGE + '[export]\nstage = "zz"\n',
    "[export]: path_from = 'zz' is no stage": STAGE + '[export]\nstage = "a"\npath_from = "zz"\n',
    "[export]: args: --out is set by the recipe runner": STAGE + '[export]\nstage = "a"\nargs = "--out x"\n',
    "no [[stage]] (nor a base with stages): nothing to run": 'name = "empty"\n',
    "name = '..': it names the default run folder": 'name = ".."\n' + STAGE,
    "stage 'b': init 'c' is no earlier stage": STAGE + '[[stage]]\nname = "b"\ninit = "c"\n',
    "Invalid value": STAGE + "wall_s = long\n",  # TOML itself
}
NOT_A_FOLDER_NAME = ["..", ".", "a/b", "/tmp/x", "", "model", "train.pack", "a\\b", " a"]


def _refused(text: str | bytes, tmp_path: Path, capsys, dry_run: bool = True) -> str:
    """`tween train --recipe FILE` of a recipe holding ``text``: refused (one line, exit 2,
    nothing written) with nothing on stdout either, its line naming the file."""
    recipe = tmp_path / "r.toml"
    recipe.write_bytes(text if isinstance(text, bytes) else text.encode())
    keep = _Kept(capsys)
    args = ["train", "--recipe", recipe, "--out", tmp_path / "runs"] + ["--dry-run"] * dry_run
    line = refused(args, keep, tmp_path)
    assert keep.out == "", keep.out
    assert str(recipe) in line, line
    return line


class _Kept:
    """capsys, keeping the stdout of the last read (`refused` reads it and lets it go)."""

    def __init__(self, capsys):
        self.capsys, self.out = capsys, ""

    def readouterr(self):
        got = self.capsys.readouterr()
        self.out = got.out
        return got


@pytest.mark.parametrize("want", list(BAD))
def test_a_malformed_recipe_is_refused_naming_the_file_and_key(want, tmp_path, capsys):
    for dry_run in (True, False):  # checked on load: a replay refuses it as a dry run does
        line = _refused(BAD[want], tmp_path, capsys, dry_run)
        assert want in line, line


def test_a_recipe_that_is_not_utf8_text_or_not_a_file_is_refused(tmp_path, capsys):
    assert "not UTF-8 text" in _refused(b"\xff\xfe[[stage]]\n", tmp_path, capsys)
    folder = tmp_path / "dir.toml"
    folder.mkdir()
    line = refused(["train", "--recipe", folder, "--dry-run"], capsys, tmp_path)
    assert f"{folder}: cannot read it" in line, line


@pytest.mark.parametrize("name", NOT_A_FOLDER_NAME)
def test_a_stage_name_that_is_not_a_plain_folder_name_is_refused(name, tmp_path, capsys):
    # ".." ran the stage into the parent of --out (its generator.pt, logs written there).
    text = f'[[stage]]\nname = "{name.replace(chr(92), chr(92) * 2)}"\nargs = "--steps 4 --path-steps 0"\n'
    for dry_run in (True, False):
        line = _refused(text, tmp_path, capsys, dry_run)
        assert "must be a plain folder name" in line, line


def test_a_recipe_that_is_its_own_base_is_refused(tmp_path, capsys):
    me = tmp_path / "r.toml"
    line = _refused(f'base = {{recipe = "{me}"}}\n' + STAGE, tmp_path, capsys)
    assert "leads back to itself" in line, line
    other = tmp_path / "other.toml"
    other.write_text(f'base = {{recipe = "{me}"}}\n' + STAGE.replace('"a"', '"b"'))
    line = _refused(f'base = {{recipe = "{other}"}}\n' + STAGE, tmp_path, capsys)
    assert f"{other}: base: " in line and "leads back to itself" in line, line


def test_a_stage_folder_whose_checkpoint_cannot_be_read_is_refused_before_training(tmp_path, capsys):
    import torch

    recipe, out = tmp_path / "r.toml", tmp_path / "runs"
    recipe.write_text(TWO)
    (out / "b").mkdir(parents=True)
    args = ["train", "--recipe", recipe, "--out", out, "--limit-clips", "1"]
    for junk in (b"garbage\n", b"\x80\x04 not a checkpoint", None):
        ckpt = out / "b" / "generator.pt"
        if junk is None:
            torch.save([1, 2], ckpt)
        else:
            ckpt.write_bytes(junk)
        line = refused(args, capsys, tmp_path)  # stage a is not trained first
        assert line.startswith(f"tween: error: {ckpt}: ") and "remove it, or give another --out" in line, line
    torch.save({"model": {}, "config": {}, "step": "x"}, ckpt)
    assert "its step is 'x', not a number" in refused(args, capsys, tmp_path)
    ckpt.unlink()
    (out / "b").rmdir()
    (out / "b").write_text("")  # a file where the stage's folder goes
    assert f"{out / 'b'}: stage b of {recipe}" in refused(args, capsys, tmp_path)


def test_a_bare_name_is_the_shipped_recipe_whatever_the_current_folder_holds(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    shipped = RECIPES / "tween-bandai-v5.3.toml"
    (tmp_path / "tween-bandai-v5.3").mkdir()  # once: "Is a directory"
    (tmp_path / "tween-bandai-dna-v1").write_text("not a recipe")
    for name in ("tween-bandai-v5.3", "tween-bandai-dna-v1"):
        out = succeeded(["train", "--recipe", name, "--dry-run", "--out", tmp_path / "o"], capsys)
        assert f"({RECIPES / name}.toml)" in out, out
    assert shipped.exists() and not (tmp_path / "o").exists()
    # A path to a .toml file is that file, relative to the current folder; so is a file with
    # no .toml that no shipped recipe is named after.
    for name in ("mine.toml", "mine"):
        (tmp_path / name).write_text('name = "mine"\n' + STAGE)
        out = succeeded(["train", "--recipe", name, "--dry-run", "--out", tmp_path / "o"], capsys)
        assert f"# recipe mine ({name})" in out, out
    line = refused(["train", "--recipe", "nope", "--dry-run"], capsys, tmp_path)
    assert "no recipe 'nope'" in line and "tween-bandai-v5.3" in line, line


@pytest.mark.parametrize("name", sorted(p.stem for p in RECIPES.glob("*.toml")))
def test_every_shipped_recipe_dry_runs(name, tmp_path, capsys):
    out = succeeded(["train", "--recipe", name, "--dry-run", "--out", tmp_path / "o"], capsys)
    assert out.startswith(f"# recipe {name} ") and not (tmp_path / "o").exists()
