"""model.json is read by one reader (pipeline.infer.folder.read_json_object) wherever it is
read: before, a model's licence (pipeline.fill.licence) and a motion-library model
(pipeline.library.model) read it with ``read_text``, so a pipe there blocked for ever, a link
to /dev/zero read without end and deep JSON raised RecursionError. And a model folder's
damage is said as what it is: a rig.json that is a link loop was "model.json: missing", a
model.json at 1e308 fps was a line about the shot's keys."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from cli_contract import refused, succeeded
from damaged_inputs import linked_copy, replace_with
from pipe_guard import within
from usd_fixtures import bandai_shot

from pipeline.errors import TweenError

ROOT = Path(__file__).resolve().parents[2]
MODELS = ROOT / "models"


def _one_line(fn, path: Path) -> str:
    """The one-line TweenError ``fn()`` raises, naming ``path``, within a few seconds."""
    with pytest.raises(TweenError) as e:
        within(fn, [path], seconds=20)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{path}: "), msg
    return msg


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    return bandai_shot(tmp_path_factory.mktemp("walk") / "walk.usda", frames=41, keys_every=10)


@pytest.mark.parametrize("how", ["fifo", "zero", "deep"])
@pytest.mark.parametrize("file", ["model.json", "rig.json"])
def test_a_models_licence_is_read_by_the_one_reader(tmp_path, how, file):
    from pipeline.fill.licence import folder_licence

    path = tmp_path / file
    replace_with(path, how)
    msg = _one_line(lambda: folder_licence(tmp_path, file), path)
    if how != "deep":
        assert "not a regular file" in msg, msg
    else:
        assert "nested too deeply" in msg, msg


@pytest.mark.parametrize("how", ["fifo", "zero", "deep"])
def test_a_motion_library_models_json_is_read_by_the_one_reader(tmp_path, how):
    from pipeline.library.model import LibraryModel

    folder = linked_copy(MODELS / "cmu-library", tmp_path / "lib-model")
    replace_with(folder / "model.json", how)
    _one_line(lambda: LibraryModel(folder), folder / "model.json")


@pytest.mark.parametrize("how", ["fifo", "zero", "deep"])
def test_fill_local_with_a_library_model_folder_is_one_line(tmp_path, capsys, walk, how):
    folder = linked_copy(MODELS / "cmu-library", tmp_path / "lib-model")
    replace_with(folder / "model.json", how)
    argv = ["fill-local", walk, "--model", folder, "--out-dir", tmp_path / "out"]
    line = within(lambda: refused(argv, capsys, tmp_path), [folder / "model.json"])
    assert line.startswith(f"tween: error: {folder / 'model.json'}: "), line


@pytest.mark.parametrize("how", ["fifo", "zero", "deep"])
def test_a_model_json_damaged_after_its_model_loaded_is_one_line_not_a_hang(tmp_path, capsys, walk, how):
    """A process that fills again (a farm worker) keeps its loaded model, but reads the
    model's licence at every fill: a model.json replaced by a pipe then blocked it for ever."""
    folder = linked_copy(MODELS / "default", tmp_path / "mdl")
    argv = ["fill-local", walk, "--model", folder, "--trust", "model", "--out-dir"]
    succeeded([*argv, tmp_path / "first"], capsys)
    replace_with(folder / "model.json", how)
    line = within(lambda: refused([*argv, tmp_path / "again"], capsys, tmp_path), [folder / "model.json"])
    assert line.startswith(f"tween: error: {folder / 'model.json'}: "), line
    assert not (tmp_path / "again").exists()


# -- what the damage is, said as it is -------------------------------------------------------
def test_a_rig_json_that_is_a_link_loop_is_named_as_one(tmp_path, capsys, walk):
    folder = linked_copy(MODELS / "elephant", tmp_path / "eleph")
    (folder / "rig.json").unlink()
    (folder / "rig.json").symlink_to("rig.json")  # leads back to itself
    line = refused(["fill-local", walk, "--model", folder, "--out-dir", tmp_path / "out"], capsys, tmp_path)
    assert (
        line == f"tween: error: {folder / 'rig.json'}: a link loop (it leads back to itself), not a rig.json"
    )


def test_a_generator_linked_to_a_device_is_not_a_regular_file(tmp_path, capsys, walk):
    folder = linked_copy(MODELS / "default", tmp_path / "mdl")
    (folder / "generator.onnx").unlink()
    (folder / "generator.onnx").symlink_to("/dev/zero")
    line = refused(["fill-local", walk, "--model", folder, "--out-dir", tmp_path / "out"], capsys, tmp_path)
    assert line.startswith(f"tween: error: {folder / 'generator.onnx'}: not a regular file"), line
    assert "empty" not in line


@pytest.mark.parametrize("fps", ["1e308", "Infinity", "NaN", "0", "-30", "1001"], ids=lambda v: f"fps={v}")
def test_a_model_json_frame_rate_out_of_range_is_one_line_naming_it_and_no_warning(tmp_path, walk, fps):
    """Before: 1e308 printed two numpy RuntimeWarnings and a line about the shot's keys;
    Infinity (which Python's JSON reader takes) passed the model.json check."""
    folder = linked_copy(MODELS / "default", tmp_path / "mdl")
    text = (MODELS / "default" / "model.json").read_text()
    meta = json.loads(text)
    (folder / "model.json").unlink()
    (folder / "model.json").write_text(text.replace(f'"fps": {json.dumps(meta["fps"])}', f'"fps": {fps}', 1))
    assert f'"fps": {fps}' in (folder / "model.json").read_text()
    r = subprocess.run(
        [sys.executable, "-m", "pipeline.cli", "fill-local", str(walk), "--model", str(folder),
         "--out-dir", str(tmp_path / "out")],
        capture_output=True, text=True, timeout=120, env={**os.environ, "PYTHONWARNINGS": "default"},
    )  # fmt: skip
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    want = f"tween: error: {folder / 'model.json'}: 'fps' must be a number of frames a second above 0"
    assert lines[0].startswith(want), lines[0]
    assert not (tmp_path / "out").exists()
