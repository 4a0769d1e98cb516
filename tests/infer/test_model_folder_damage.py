"""A damaged file in a model folder (or a recipe, a corpus, a library manifest) is one
TweenError naming it, at once: a pipe in place of a file blocked the reader for ever, a link
to /dev/zero read without end, JSON or TOML nested too deeply raised RecursionError, and
numbers in model.json, rig.json or a pose bank's header asked for gigabytes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from damaged_inputs import DEEP_JSON, DEEP_TOML, linked_copy, replace_with
from pipe_guard import within

from pipeline.errors import TweenError

ROOT = Path(__file__).resolve().parents[2]
MODELS = ROOT / "models"


def _fails_fast(load, path: Path, seconds: float = 20.0) -> str:
    """The one-line TweenError ``load()`` raises, naming ``path``; fails where it hangs."""
    try:
        within(load, [path], seconds)
    except BaseException as err:  # noqa: BLE001 (what it raised is what the test checks)
        e = err
    else:
        pytest.fail(f"loading with a damaged {path.name} raised nothing")
    assert isinstance(e, TweenError | ValueError), f"{type(e).__name__}: {e}"
    if not isinstance(e, TweenError):  # RecipeError is a ValueError the CLI reports as one line
        assert type(e).__name__ == "RecipeError", f"{type(e).__name__}: {e}"
    msg = str(e)
    assert "\n" not in msg and str(path) in msg, msg
    return msg


# -- the human model folder ------------------------------------------------------------------
def _human(tmp_path: Path) -> Path:
    folder = linked_copy(MODELS / "default", tmp_path / "mdl")
    (folder / "model.json").unlink()
    (folder / "model.json").write_text((MODELS / "default" / "model.json").read_text())
    return folder


def _meta_with(folder: Path, **changes) -> str:
    meta = json.loads((MODELS / "default" / "model.json").read_text())
    meta.update(changes)
    return json.dumps(meta)


@pytest.mark.parametrize(
    "name, how",
    [
        ("model.json", "fifo"),
        ("model.json", "zero"),
        ("model.json", "deep"),
        ("model.json", "multiple"),
        ("generator.onnx", "fifo"),
        ("delta/model.json", "deep"),
    ],
)
def test_damaged_human_model_file(tmp_path, name, how):
    from pipeline.infer.api import folder_kind, load_folder

    folder = _human(tmp_path)
    target = folder
    if name.startswith("delta/"):
        target = linked_copy(MODELS / "default" / "delta", folder / "delta_copy")
        name = name.split("/", 1)[1]
    payload = {"deep": DEEP_JSON, "multiple": _meta_with(folder, multiple=10**9)}.get(how, "")
    replace_with(target / name, how, payload)
    msg = _fails_fast(lambda: load_folder(target), target / name)
    if how == "multiple":
        assert "'multiple'" in msg
    elif name == "model.json":  # the kind is read first, for the registry
        _fails_fast(lambda: folder_kind(target), target / name)


@pytest.mark.parametrize("dtype, poses", [(np.float16, 1_100_000), (np.complex64, 16)])
def test_pose_bank_header_is_checked_before_its_data(tmp_path, dtype, poses):
    from pipeline.infer.api import load_folder

    folder = _human(tmp_path)
    bank = folder / "pose_bank.npz"
    bank.unlink()
    np.savez_compressed(bank, poses=np.zeros((poses, 21, 3), dtype), version=1, source="x")
    assert bank.stat().st_size < 2_000_000  # a small file declaring more poses than a bank holds
    _fails_fast(lambda: load_folder(folder), bank)


# -- rig models ------------------------------------------------------------------------------
def _rig(tmp_path: Path, how: str) -> Path:
    folder = linked_copy(MODELS / "elephant", tmp_path / "models" / "eleph")
    meta = json.loads((MODELS / "elephant" / "rig.json").read_text())
    meta["levels"][0]["train_length"] = 10**9
    payload = {"deep": DEEP_JSON, "train_length": json.dumps(meta)}.get(how, "")
    replace_with(folder / "rig.json", how, payload)
    return folder


@pytest.mark.parametrize("how", ["fifo", "zero", "deep", "train_length"])
def test_damaged_rig_json(tmp_path, how):
    from pipeline.infer.api import load_folder
    from pipeline.rig.infer import RigInbetweener

    folder = _rig(tmp_path, how)
    _fails_fast(lambda: load_folder(folder, "rig.json"), folder / "rig.json")
    if how == "train_length":
        _fails_fast(lambda: RigInbetweener(folder), folder / "rig.json")


def test_a_deep_rig_json_in_the_store_is_skipped_with_a_warning(tmp_path, capsys):
    from pipeline.rig.store import read_rig_json, rig_models

    folder = _rig(tmp_path, "deep")
    _fails_fast(lambda: read_rig_json(folder), folder / "rig.json")
    assert rig_models(folder.parent) == []
    assert "skipping rig model" in capsys.readouterr().err


# -- a library, a recipe, a corpus -------------------------------------------------------------
@pytest.mark.parametrize("how", ["fifo", "zero", "deep"])
def test_damaged_library_manifest(tmp_path, how):
    from pipeline.library.store import open_library

    lib = linked_copy(MODELS / "default" / "library", tmp_path / "lib")
    replace_with(lib / "library.json", how, DEEP_JSON)
    _fails_fast(lambda: open_library(lib), lib / "library.json")


@pytest.mark.parametrize("how", ["fifo", "zero", "deep"])
def test_damaged_recipe(tmp_path, how):
    from pipeline.train.recipe import load_recipe

    path = tmp_path / "r.toml"
    replace_with(path, how, DEEP_TOML)
    _fails_fast(lambda: load_recipe(path), path)


@pytest.mark.parametrize("how", ["fifo", "zero", "deep"])
def test_damaged_corpus(tmp_path, how):
    from pipeline.data.corpus import load_corpus

    path = tmp_path / "c.toml"
    replace_with(path, how, DEEP_TOML)
    _fails_fast(lambda: load_corpus(path), path)


def test_read_small_text_bounds_what_it_reads(tmp_path):
    from pipeline.inputs import NotReadable, read_small_text

    path = tmp_path / "big.json"
    path.write_text("x" * 101)
    assert read_small_text(path, 101, "model.json") == "x" * 101
    with pytest.raises(NotReadable, match="larger than 100 bytes"):
        read_small_text(path, 100, "model.json")
    with pytest.raises(NotReadable, match="a folder"):
        read_small_text(tmp_path, 100, "model.json")
    with pytest.raises(FileNotFoundError):
        read_small_text(tmp_path / "none", 100, "model.json")
