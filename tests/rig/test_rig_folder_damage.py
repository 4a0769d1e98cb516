"""A damaged rig model folder is named in one line when it loads (or when a level's session
starts), never an internal error from onnxruntime, numpy or a missing rig.json key."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import TweenError
from pipeline.infer.folder import files_hash
from pipeline.rig.infer import RigInbetweener

ELEPHANT = Path(__file__).resolve().parents[2] / "models" / "elephant"


def _copy(tmp_path: Path, edit=None) -> Path:
    folder = tmp_path / "rig"
    shutil.copytree(ELEPHANT, folder)
    if edit is not None:
        meta = json.loads((folder / "rig.json").read_text())
        edit(meta)
        (folder / "rig.json").write_text(json.dumps(meta))
    return folder


def _pop(key):
    return lambda m: m.pop(key)


@pytest.mark.parametrize(
    "edit, says",
    [
        (lambda m: m.update(contact_joints=["nope"]), "not a rig model: no joint named 'nope'"),
        (lambda m: m.update(ik_joints=["nope"]), "not a rig model: no joint named 'nope'"),
        (_pop("representation"), "not a rig model: missing 'representation'"),
        (lambda m: m.update(levels=[]), "not a rig model: no levels"),
        (lambda m: m["representation"].update(scale=0), "representation scale must be a positive number"),
        (lambda m: m["representation"].update(scale=float("nan")), "representation scale must be a positive"),
        (lambda m: m.update(fps=0), "fps 0.0 is not a positive number"),
    ],
)
def test_a_rig_json_a_fill_cannot_use_is_named(tmp_path, edit, says):
    folder = _copy(tmp_path, edit)
    with pytest.raises(TweenError) as e:
        RigInbetweener(folder)
    assert str(e.value).startswith(f"{folder / 'rig.json'}: ") and says in str(e.value)


def test_a_damaged_or_foreign_level_file_is_named(tmp_path):
    folder = _copy(tmp_path)
    level = folder / "level_3.onnx"
    level.write_bytes(level.read_bytes()[:3000])
    with pytest.raises(TweenError, match=r"level_3\.onnx: truncated or not an ONNX model \(3000 bytes\)"):
        RigInbetweener(folder)
    level.write_bytes(b"")
    with pytest.raises(TweenError, match=r"level_3\.onnx: empty file"):
        RigInbetweener(folder)
    # A whole ONNX file of another network: refused at load by the hash rig.json states; with
    # a hash that fits (hand-made), named when its session starts.
    shutil.copyfile(ELEPHANT.parents[0] / "default" / "path.onnx", level)
    with pytest.raises(TweenError, match=r"rig\.json: 'hash' is '477c17f1cd93d7c8' but its files"):
        RigInbetweener(folder)
    meta = json.loads((folder / "rig.json").read_text())
    meta["hash"] = files_hash(folder, meta["files"]["levels"])
    (folder / "rig.json").write_text(json.dumps(meta))
    rig = RigInbetweener(folder)
    with pytest.raises(TweenError, match=r"level_3\.onnx: not this rig's level 2"):
        rig.level(2, np.zeros((rig.spec.channels, 32), np.float32), np.zeros(32, np.float32))
