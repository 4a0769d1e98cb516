"""The shipped generator's padded window, the settings it refuses, and posture-offset augmentation."""

import numpy as np
import pytest

from pipeline.infer.generator_onnx import OnnxInbetweener
from pipeline.motion.augment import posture_offsets
from pipeline.motion.bvh import read_bvh
from pipeline.motion.rotations import quat_inv, quat_mul


@pytest.fixture(scope="module")
def clip(bandai_clip):
    m = read_bvh(bandai_clip).continuous()
    return m.rotations[None, :100].astype(np.float32), m.root_positions[None, :100].astype(np.float32)


def test_the_fill_keeps_keys_and_holds_outside_them(clip):
    rot, root = clip
    keys = np.array([5, 6, 7, 20, 41, 70])  # 66 keyed frames: padded
    q, r = OnnxInbetweener("models/default").fill_batch(rot, root, keys)
    assert np.array_equal(q[0, keys], rot[0, keys]) and np.array_equal(r[0, keys], root[0, keys])
    assert (q[0, :5] == rot[0, 5]).all() and (r[0, 71:] == root[0, 70]).all()
    assert np.isfinite(q).all() and np.isfinite(r).all()


def _spy_features(model, monkeypatch) -> dict:
    """Record the features the generator session is run on."""
    seen = {}
    real = model.session("generator").run

    class Spy:
        def run(self, names, feeds):
            seen["feats"] = feeds["features"]
            return real(names, feeds)

    monkeypatch.setitem(model._sessions, "generator", Spy())
    return seen


KEY_FLAG = 2 * (21 * 6 + 3) + 1  # the key-flag channel of the features


def test_hold_key_pads_with_a_key_at_the_end(clip, monkeypatch):
    rot, root = clip
    model = OnnxInbetweener("models/default")
    seen = _spy_features(model, monkeypatch)
    model.raw(rot[:, :40], root[:, :40], np.array([0, 10, 39]))
    is_key = seen["feats"][0, KEY_FLAG]
    assert len(is_key) == 64 and np.flatnonzero(is_key).tolist() == [0, 10, 39, 63]


@pytest.mark.parametrize(
    ("span", "tail", "min_window", "padded"),
    [(26, 0, 0, 32), (26, 16, 64, 64), (56, 16, 64, 96), (56, 0, 64, 64), (80, 16, 64, 96), (81, 16, 0, 128)],
)
def test_padded_window_length(clip, monkeypatch, span, tail, min_window, padded):
    rot, root = clip
    model = OnnxInbetweener("models/default")
    model.pad_tail, model.min_window = tail, min_window
    seen = _spy_features(model, monkeypatch)
    keys = np.array([0, 1, 2, 9, span - 1])
    q, r, _ = model.raw(rot[:, :span], root[:, :span], keys)
    is_key = seen["feats"][0, KEY_FLAG]
    assert len(is_key) == padded and np.flatnonzero(is_key).tolist() == [*keys, padded - 1]
    assert q.shape[1] == span and r.shape[1] == span


@pytest.mark.parametrize(
    ("key", "value"), [("pad", "end"), ("root", "path"), ("mirror_average", True), ("rotation", "euler")]
)
def test_settings_no_release_runs_are_refused(tmp_path, key, value):
    """A model folder set up for a layout, root source, test-time mirror or network output
    that no shipped model used is refused by name (the code for them is gone)."""
    import json
    import shutil

    folder = tmp_path / "m"
    shutil.copytree("models/default", folder, ignore=shutil.ignore_patterns("torch", "bench", "*.md"))
    meta = json.loads((folder / "model.json").read_text())
    (meta["generator"] if key == "rotation" else meta)[key] = value
    (folder / "model.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=f"{key}.*this release runs"):
        OnnxInbetweener(folder)


def test_posture_offsets_are_constant_per_joint_and_bounded(clip):
    rot = np.repeat(clip[0][:, :30], 6, axis=0)
    out = posture_offsets(rot, np.random.default_rng(1), 30.0, 0.5)
    off = quat_mul(quat_inv(rot.astype(np.float64)), out.astype(np.float64))  # rot⁻¹ · out
    off = np.where(off[..., 3:] < 0, -off, off)
    assert np.abs(off - off[:, :1]).max() < 1e-4  # the same offset on every frame
    angle = np.degrees(2 * np.arccos(np.clip(off[..., 3], -1, 1)))
    assert angle.max() <= 30.0 + 1e-3
    touched = angle.max(axis=(1, 2)) > 1e-3
    assert 0 < touched.sum() < 6  # about half the windows
    assert np.allclose(posture_offsets(rot, np.random.default_rng(1), 30.0, 0.0), rot, atol=1e-6)


def test_inference_settings_are_part_of_the_model_hash(tmp_path):
    pytest.importorskip("torch")
    from pipeline.train.export import model_hash

    (tmp_path / "g.onnx").write_bytes(b"weights")
    meta = {"files": {"generator": "g.onnx"}, "root": "generator"}
    legacy = model_hash(tmp_path, meta)
    assert model_hash(tmp_path, {**meta, "pad": "hold-key"}) not in (
        legacy,
        model_hash(tmp_path, {**meta, "pad": "end"}),
    )
    (tmp_path / "g.onnx").write_bytes(b"other weights")
    assert model_hash(tmp_path, meta) != legacy
