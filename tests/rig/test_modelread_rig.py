"""A rig model folder's damage said as what it is: a rig.json at 0 fps was refused only later,
by the shot's keys (or taken: the store read any number); a rig.json that is a link loop was
"no rig.json"; a level linked to /dev/zero was "missing"; and a crafted train-rig state.pt,
which torch.load(weights_only=True) refuses as unsafe, was called "damaged"."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from cli_contract import refused
from damaged_inputs import linked_copy
from usd_fixtures import bandai_shot

from pipeline.errors import TweenError

ROOT = Path(__file__).resolve().parents[2]
ELEPHANT = ROOT / "models" / "elephant"


def _rig_with(tmp_path: Path, **changes) -> Path:
    folder = linked_copy(ELEPHANT, tmp_path / "eleph")
    meta = json.loads((ELEPHANT / "rig.json").read_text()) | changes
    (folder / "rig.json").unlink()
    (folder / "rig.json").write_text(json.dumps(meta))
    return folder


@pytest.mark.parametrize("fps", [0, -24, 1e308, float("inf"), float("nan"), 5000], ids=str)
def test_a_rig_json_frame_rate_out_of_range_is_refused_when_the_file_is_read(tmp_path, capsys, fps):
    from pipeline.rig.infer import RigInbetweener
    from pipeline.rig.store import read_rig_json, rig_models

    folder = _rig_with(tmp_path, fps=fps)
    path = folder / "rig.json"
    want = f"{path}: not a rig model: 'fps' must be a number of frames a second above 0 and at most 1,000"
    with pytest.raises(TweenError) as e:
        read_rig_json(folder)  # the store, which a fill asks first
    assert str(e.value).startswith(want) and "\n" not in str(e.value), e.value
    with pytest.raises(TweenError) as e:
        RigInbetweener(folder)  # the model's own loader
    assert str(e.value).startswith(
        f"{path}: not a rig model: fps {float(fps)!r} is not a positive number of at most 1,000"
    )
    assert rig_models(folder.parent) == []  # the store skips it, saying so
    assert f"{path}" in capsys.readouterr().err
    shot = bandai_shot(tmp_path / "walk.usda", frames=41, keys_every=10)
    line = refused(["fill-local", shot, "--model", folder, "--out-dir", tmp_path / "out"], capsys, tmp_path)
    assert line.startswith(f"tween: error: {want}"), line


def test_a_rig_json_link_loop_is_named_by_every_reader(tmp_path):
    from pipeline.rig.infer import RigInbetweener
    from pipeline.rig.store import read_rig_json

    folder = linked_copy(ELEPHANT, tmp_path / "eleph")
    path = folder / "rig.json"
    path.unlink()
    path.symlink_to(path)
    for read in (read_rig_json, RigInbetweener):
        with pytest.raises(TweenError) as e:
            read(folder)
        assert str(e.value).startswith(f"{path}: ") and "a link loop (it leads back to itself)" in str(
            e.value
        )


def test_a_level_linked_to_a_device_is_not_a_regular_file_nor_missing(tmp_path):
    from pipeline.rig.infer import RigInbetweener

    folder = linked_copy(ELEPHANT, tmp_path / "eleph")
    level = folder / "level_1.onnx"
    level.unlink()
    level.symlink_to("/dev/zero")
    with pytest.raises(TweenError) as e:
        RigInbetweener(folder)
    msg = str(e.value)
    assert msg.startswith(f"{level}: not a regular file (a pipe, socket or device)"), msg
    assert "missing" not in msg and "\n" not in msg


class _Evil:
    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def _bare_trainer(tmp_path: Path):
    from pipeline.rig.train import Trainer

    torch = pytest.importorskip("torch")
    bare = type("Bare", (Trainer,), {"ckpt_dir": tmp_path, "device": torch.device("cpu")})
    return bare.__new__(bare)  # only what _read_state reads


def test_a_crafted_rig_state_is_refused_for_safety_not_called_damaged(tmp_path):
    torch = pytest.importorskip("torch")
    from pipeline.rig.train import TrainError

    marker = tmp_path / "PWNED"
    path = tmp_path / "state.pt"
    torch.save({"step": _Evil(marker)}, path)
    with pytest.raises(TrainError) as e:
        _bare_trainer(tmp_path)._read_state(path)
    msg = str(e.value)
    assert msg.startswith(
        f"{path}: the training checkpoint holds something other than tensors and plain values "
        "and was refused for safety"
    ), msg
    assert "damaged" not in msg and "\n" not in msg and not marker.exists()


def test_a_cut_rig_state_is_still_damaged(tmp_path):
    torch = pytest.importorskip("torch")
    from pipeline.rig.train import TrainError

    path = tmp_path / "state.pt"
    torch.save({"a": torch.zeros(3)}, path)
    path.write_bytes(path.read_bytes()[:100])
    with pytest.raises(TrainError, match="the training checkpoint is damaged"):
        _bare_trainer(tmp_path)._read_state(path)
