"""Filling shots with per-rig models: model choice per character, the rig path through the
writer (keys bitwise), provenance, digest, refusals; the elephant with a rig model."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from test_rig_store import NAMES, OFFSETS, PARENTS, write_rig
from usd_fixtures import ELEPHANT, bandai_shot, tree_hashes

from pipeline.errors import TweenError
from pipeline.fill import api as fill
from pipeline.fill.api import FillOptions, fill_shot, validate_shot
from pipeline.motion.clip import Motion
from pipeline.motion.rotations import euler_to_quat
from pipeline.motion.skeleton import Skeleton
from pipeline.rig.infer import RigInbetweener

CREATURE_ANIM = "/World/Creature/Skel/Anim"


def creature_motion(T: int = 61, fps: float = 30.0) -> Motion:
    """A small quadruped-ish rig (no human mapping) walking forward with swinging legs."""
    skel = Skeleton(NAMES, np.array(PARENTS), OFFSETS.astype(np.float32), "Y", 0.01)
    t = np.arange(T) / fps
    J = len(NAMES)
    ang = np.zeros((T, J, 3))
    ang[:, 0, 1] = 20 * np.sin(0.5 * t)  # root yaw
    ang[:, 1, 0] = 10 * np.sin(2 * t)
    ang[:, 2, 0] = 15 * np.sin(3 * t + 1)
    ang[:, 3, 1] = 30 * np.sin(4 * t)
    ang[:, 4, 0] = 35 * np.sin(5 * t)
    ang[:, 5, 0] = 20 * np.sin(5 * t + 0.5) + 20
    ang[:, 6, 0] = -35 * np.sin(5 * t)
    ang[:, 7, 0] = 20 * np.sin(5 * t + 2) + 20
    rot = euler_to_quat(ang.reshape(-1, 3), "XYZ").reshape(T, J, 4)
    root = np.stack([5 * np.sin(t), 60 + 2 * np.sin(10 * t), 80 * t], axis=1)
    return Motion(skel, rot, root, fps, "creature")


def creature_shot(path: Path, T: int = 61, keys_every: int = 10, **kw) -> Path:
    from pipeline.usd.convert import write_shot

    write_shot(creature_motion(T), path, keys_every=keys_every, name="Creature", **kw)
    return path


def rig_from_shot(folder: Path, shot: Path, skeleton: str | None = None, **kw) -> Path:
    """A rig.json for the shot's skeleton, written the way the rig source reads it."""
    from pipeline.rig.source import load_rig_source

    m = load_rig_source(shot, skeleton)
    s = m.skeleton
    return write_rig(folder, s.names, s.parents.tolist(), s.offsets, s.meters_per_unit, s.up_axis, **kw)


class FakeRig:
    """Stands in for pipeline.rig.infer.RigInbetweener: SLERP/LERP between keys on the rig
    skeleton, plus a seed-dependent sway so takes differ; records every call."""

    capabilities = RigInbetweener.capabilities  # declared, as every in-betweener's
    calls: list = []

    def __init__(self, folder):
        meta = json.loads((Path(folder) / "rig.json").read_text())
        sk = meta["skeleton"]
        self.meta, self.name, self.model_hash, self.fps = meta, meta["name"], meta["hash"], float(meta["fps"])
        self.skeleton = Skeleton(sk["names"], np.array(sk["parents"]), np.array(sk["offsets"]), sk["up_axis"],
                                 sk["meters_per_unit"])  # fmt: skip

    def fill(self, motion, keys, seed=0):
        from pipeline.infer.interp import interpolate_keys

        assert motion.skeleton is self.skeleton and motion.fps == self.fps
        FakeRig.calls.append(
            (self.name, motion.rotations[keys].copy(), motion.root_positions[keys].copy(), seed)
        )
        out = interpolate_keys(motion, keys)
        if seed:
            sway = np.zeros(len(out), np.float32)
            for a, b in zip(keys[:-1], keys[1:], strict=True):
                sway[a + 1 : b] = np.sin(np.linspace(0, np.pi, b - a + 1)[1:-1]) * seed
            out.root_positions[:, 0] += sway
        return out


@pytest.fixture
def models(tmp_path, monkeypatch):
    """An empty models root of its own (with the shipped human model linked in) and the fake rig model class."""
    root = tmp_path / "models"
    root.mkdir()
    shipped = Path(fill.__file__).resolve().parents[2] / "models" / "default"
    if shipped.is_dir():
        (root / "default").symlink_to(shipped)
    monkeypatch.setenv("TWEEN_MODELS", str(root))
    monkeypatch.setattr(fill, "_load_rig", FakeRig)
    fill._MODELS.clear()
    FakeRig.calls = []
    yield root
    fill._MODELS.clear()


def _anim(layer_path, anim):
    from pxr import Usd

    stage = Usd.Stage.Open(str(layer_path))
    return stage, stage.GetPrimAtPath(anim + "_tween")


def test_rig_character_fills_with_its_rig_model_keys_bitwise(tmp_path, models):
    from pxr import Sdf, Usd

    shot = creature_shot(tmp_path / "shots" / "cr010.usda")
    rig = rig_from_shot(models / "creature", shot)
    before = tree_hashes(shot.parent)
    summary = validate_shot(str(shot), FillOptions())
    assert summary["models"][CREATURE_ANIM]["kind"] == "rig"
    assert summary["models"][CREATURE_ANIM]["name"] == "creature"
    assert summary["model"] == "creature" and summary["model_hash"] == "hash-creature"
    res = fill_shot(str(shot), FillOptions(out_dir=str(tmp_path / "out")))
    assert res["model"] == "creature" and res["models"] == {CREATURE_ANIM: "creature"}
    assert tree_hashes(shot.parent) == before

    src_stage = Usd.Stage.Open(str(shot))
    src = src_stage.GetPrimAtPath(CREATURE_ANIM)
    stage, filled = _anim(res["review"], CREATURE_ANIM)
    assert filled.GetAttribute("tween:model").Get() == "creature"
    assert filled.GetAttribute("tween:modelHash").Get() == "hash-creature"
    info = Sdf.Layer.FindOrOpen(res["layer"]).customLayerData["tween"]
    assert info["model"] == "creature" and dict(info["models"]) == {CREATURE_ANIM: "creature"}
    keys = src.GetAttribute("rotations").GetTimeSamples()
    assert keys == [1001.0 + 10 * i for i in range(7)]
    for attr in ("rotations", "translations", "scales"):
        a, b = src.GetAttribute(attr), filled.GetAttribute(attr)
        for t in keys:  # keys: the authored arrays, bit for bit
            assert np.array_equal(np.array(a.Get(t)), np.array(b.Get(t)), equal_nan=False), (attr, t)
    assert filled.GetAttribute("rotations").GetTimeSamples() == [1001.0 + i for i in range(61)]
    # Between keys: the (fake) model's SLERP on the rig's own joints, in skeleton order.
    rot = np.array(filled.GetAttribute("rotations").Get(1005))
    q0, q1 = (
        np.array(src.GetAttribute("rotations").Get(1001)),
        np.array(src.GetAttribute("rotations").Get(1011)),
    )
    from pipeline.motion.rotations import slerp

    want = slerp(q0, q1, [0.4])[0]
    np.testing.assert_allclose(np.abs((rot * want).sum(-1)), 1.0, atol=1e-6)
    tr = np.array(filled.GetAttribute("translations").Get(1005))
    t0, t1 = (
        np.array(src.GetAttribute("translations").Get(1001)),
        np.array(src.GetAttribute("translations").Get(1011)),
    )
    np.testing.assert_allclose(tr[0], 0.6 * t0[0] + 0.4 * t1[0], atol=1e-4)
    np.testing.assert_array_equal(tr[1:], t0[1:])  # bone offsets stay the rig's
    # The model saw the keys in its own joint order and space: here the shot's own values.
    (name, krot, kroot, seed) = FakeRig.calls[-1]
    assert name == "creature" and seed == 0
    assert np.array_equal(krot[0], np.array(src.GetAttribute("rotations").Get(1001)))
    assert np.array_equal(kroot[0], np.array(src.GetAttribute("translations").Get(1001))[0])
    assert rig.name == "creature"


def test_takes_seeds_and_digest_include_the_rig_model(tmp_path, models):
    shot = creature_shot(tmp_path / "cr020.usda", T=31)
    rig_from_shot(models / "creature", shot)
    work = tmp_path / "work"
    opts = FillOptions(takes=2, seed=3)
    a0 = fill.fill_take(str(shot), opts, 0, str(work))
    a1 = fill.fill_take(str(shot), opts, 1, str(work))
    assert [c[3] for c in FakeRig.calls] == [3, 4]
    t0, t1 = fill.load_take(a0), fill.load_take(a1)
    assert t0["chars"][0]["model"] == "creature" and t0["chars"][0]["model_kind"] == "rig"
    assert not np.array_equal(t0["data"][0]["trans"], t1["data"][0]["trans"])
    assert fill.fill_take(str(shot), opts, 0, str(work)) == a0  # same inputs, same file
    # Retrained model (new hash): a new digest, so no stale take is reused.
    meta = json.loads((models / "creature" / "rig.json").read_text())
    meta["hash"] = "hash-retrained"
    (models / "creature" / "rig.json").write_text(json.dumps(meta))
    fill._MODELS.clear()
    b0 = fill.fill_take(str(shot), opts, 0, str(work))
    assert b0 != a0 and fill.load_take(b0)["model_hash"] == "hash-retrained"
    res = fill.write_layers(str(shot), FillOptions(takes=2, seed=3, out_dir=str(tmp_path / "o")), [b0, a1])
    stage, filled = _anim(res["review"], CREATURE_ANIM)
    assert res["takes"] == 2 and filled.GetAttribute("tween:model").Get() == "creature"


def test_human_and_rig_characters_in_one_shot_each_get_their_model(tmp_path, models):
    """A shot holding a human (Bandai) and the creature: one layer, two models."""
    from pxr import Sdf, Usd

    human = bandai_shot(tmp_path / "h.usda", frames=31, keys_every=10)
    creature = creature_shot(tmp_path / "c.usda", T=31)
    rig_from_shot(models / "creature", creature)
    shot = tmp_path / "both.usda"
    layer = Sdf.Layer.CreateNew(str(shot))
    Usd.Stage.Open(layer)  # a root layer over both shots, as a layout department would make
    layer.subLayerPaths = [creature.name, human.name]
    src = Sdf.Layer.FindOrOpen(str(human))
    layer.startTimeCode, layer.endTimeCode = src.startTimeCode, src.endTimeCode
    layer.timeCodesPerSecond = src.timeCodesPerSecond
    layer.Save()
    res = fill_shot(str(shot), FillOptions(out_dir=str(tmp_path / "o")))
    human_model = fill._model("default").name
    assert res["models"] == {CREATURE_ANIM: "creature", "/World/Character/Skel/Anim": human_model}
    assert sorted(res["model"].split("+")) == sorted(["creature", human_model])
    stage = Usd.Stage.Open(res["review"])
    assert stage.GetPrimAtPath(CREATURE_ANIM + "_tween").GetAttribute("tween:model").Get() == "creature"
    got = stage.GetPrimAtPath("/World/Character/Skel/Anim_tween").GetAttribute("tween:model").Get()
    assert got == human_model
    # Interpolation needs no model skeleton: both are interpolated, each on its own rig.
    res = fill_shot(str(shot), FillOptions(model="interp", out_dir=str(tmp_path / "o2")))
    assert res["models"] == {CREATURE_ANIM: "interpolation", "/World/Character/Skel/Anim": "interpolation"}
    # Forcing the human model leaves the creature without a model: skipped with the hint.
    human_folder = str(Path(__file__).parents[2] / "models" / "default")
    res = fill_shot(str(shot), FillOptions(model=human_folder, out_dir=str(tmp_path / "o3")))
    assert list(res["models"]) == ["/World/Character/Skel/Anim"]


def test_rig_without_model_is_refused_with_the_train_hint(tmp_path, models, capfd):
    shot = creature_shot(tmp_path / "cr030.usda", T=21)
    with pytest.raises(TweenError) as ei:
        fill_shot(str(shot), FillOptions(out_dir=str(tmp_path / "o")))
    msg = str(ei.value)
    assert "\n" not in msg and str(shot) in msg and "rig refused: joints do not map" in msg
    assert (
        f"/World/Creature/Skel (8 joints, root Root) matches no human mapping and no rig model in {models}/; "
        f"train one with: tween train-rig {shot} --skeleton /World/Creature/Skel --out {models}/cr030"
    ) in msg
    assert not (tmp_path / "o").exists()
    # Through the CLI: one line, exit 2.
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "fill-local", str(shot), "--out", str(tmp_path / "o")],
                       capture_output=True, text=True, env={**__import__("os").environ, "TWEEN_MODELS": str(models)})  # fmt: skip
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.strip().count("\n") == 0 and "train-rig" in r.stderr
    # A rig model of another creature (a longer neck) does not fit either.
    write_rig(models / "other", offsets=OFFSETS * np.r_[1, 1, 1.5, 1, 1, 1, 1, 1][:, None])
    with pytest.raises(TweenError, match="no rig model"):
        fill_shot(str(shot), FillOptions(out_dir=str(tmp_path / "o")))
    # Forced onto it, the reason is the bone that differs.
    with pytest.raises(TweenError) as ei:
        fill_shot(str(shot), FillOptions(model="other", out_dir=str(tmp_path / "o")))
    assert "does not fit rig model other" in str(ei.value) and "bone 'Head'" in str(ei.value)
    # A forced rig model that is not there: the human-model lookup's one-line error.
    with pytest.raises(TweenError, match="no such model"):
        fill_shot(str(shot), FillOptions(model="nope", out_dir=str(tmp_path / "o")))


def test_forced_rig_model_by_folder_and_human_shot_unaffected(tmp_path, models):
    shot = creature_shot(tmp_path / "cr040.usda", T=21)
    elsewhere = rig_from_shot(tmp_path / "my_models" / "creature_v2", shot, name="creature-v2")
    res = fill_shot(str(shot), FillOptions(model=str(elsewhere), out_dir=str(tmp_path / "o")))
    assert res["model"] == "creature-v2"
    human = bandai_shot(tmp_path / "h.usda", frames=21, keys_every=10)
    with pytest.raises(TweenError, match="does not fit rig model creature-v2"):
        fill_shot(str(human), FillOptions(model=str(elsewhere), out_dir=str(tmp_path / "o")))
    rig_from_shot(models / "creature", shot)
    res = fill_shot(str(human), FillOptions(out_dir=str(tmp_path / "o")))
    assert res["model"] == fill._model("default").name and FakeRig.calls[-1][0] == "creature-v2"


def test_skeleton_space_agrees_with_the_rig_source(tmp_path):
    """The fill reads a character's up axis and unit exactly as training read the clip."""
    from pipeline.adapt.rigmap import skeleton_space
    from pipeline.rig.source import load_rig_source
    from pipeline.usd.read import read_shot

    z = creature_shot(tmp_path / "z.usda", T=5, up_axis="Z")  # Z-up stage, SkelRoot rotated +90° about X
    for path, skel in ((z, None), (ELEPHANT, "/SoC_ElephantWithMonochord/Object/Elefant/_skel")):
        shot = read_shot(path)
        c = [c for c in shot.characters if skel is None or c.skel_path == skel][0]
        src = load_rig_source(path, skel).skeleton
        assert skeleton_space(c, shot.up_axis, shot.meters_per_unit) == (src.up_axis, src.meters_per_unit)
    assert skeleton_space(read_shot(z).characters[0], "Z", 0.01) == ("Y", pytest.approx(0.01))


def test_retrained_model_is_reloaded_and_a_broken_one_is_one_line(tmp_path, models, monkeypatch):
    shot = creature_shot(tmp_path / "cr050.usda", T=21)
    rig_from_shot(models / "creature", shot)
    a = fill._model(str(models / "creature"))
    assert fill._model("creature") is a  # by name or folder: one model per process
    meta = json.loads((models / "creature" / "rig.json").read_text())
    meta["hash"] = "hash-v2"
    (models / "creature" / "rig.json").write_text(json.dumps(meta))
    b = fill._model("creature")
    assert b is not a and b.model_hash == "hash-v2"

    def broken(folder):
        raise RuntimeError("[ONNXRuntimeError] : 7 : INVALID_PROTOBUF : Load model failed\nmore")

    monkeypatch.setattr(fill, "_load_rig", broken)
    meta["hash"] = "hash-v3"
    (models / "creature" / "rig.json").write_text(json.dumps(meta))
    with pytest.raises(TweenError) as ei:
        fill_shot(str(shot), FillOptions(out_dir=str(tmp_path / "o")))
    assert (
        str(ei.value)
        == f"{(models / 'creature').resolve()}: cannot load the rig model: [ONNXRuntimeError] : 7 : INVALID_PROTOBUF : Load model failed"
    )
    assert not (tmp_path / "o").exists()


def test_rigmap_up_axis_and_units_round_trip():
    from pipeline.adapt.rigmap import RigMap
    from pipeline.motion.rotations import quat_apply
    from pipeline.rig.store import RigModelInfo

    info = RigModelInfo(Path("."), "m", "h", 30.0, NAMES, np.array(PARENTS), OFFSETS, "Y", 0.01, {})
    from pipeline.motion.rotations import matrix_to_quat, quat_mul

    m = creature_motion(5)
    order = np.array([0, 3, 6, 7, 1, 2, 4, 5])  # the shot lists joints in another order
    perm = np.argsort(order)  # perm[model joint] = shot joint
    rot = m.rotations[:, order].copy()
    # ... and is Z up, in metres.
    zfix = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # Y-up → Z-up
    rot[:, perm[0]] = quat_mul(
        np.broadcast_to(matrix_to_quat(zfix), (5, 4)), m.rotations[:, 0].astype(np.float64)
    )
    tr = np.zeros((5, 8, 3), np.float32)
    tr[:, perm[0]] = (m.root_positions @ zfix.T) / 100
    rm = RigMap(None, info, perm, "Z", 1.0)
    loc, root = rm.to_model(rot, tr)
    np.testing.assert_allclose(root, m.root_positions, atol=1e-4)
    # The root's rotation is re-expressed in Y-up: same world direction for a bone.
    v = np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(quat_apply(loc[:, 0], v), quat_apply(m.rotations[:, 0], v), atol=1e-5)
    np.testing.assert_array_equal(loc[:, 1:], m.rotations[:, 1:])
    assert quat_apply(rot[0, perm[0]], np.array([0.0, 1.0, 0.0]))[2] > 0.9  # the shot's bone points up Z
    back_r, back_t = rm.from_model(loc, root, rot, tr)
    np.testing.assert_allclose(np.abs((back_r * rot).sum(-1)), 1.0, atol=1e-6)
    np.testing.assert_allclose(back_t, tr, atol=1e-6)
    # Same space: a pass-through, bit for bit.
    same = RigMap(None, info, perm, "Y", 0.01)
    loc, root = same.to_model(rot, tr)
    r2, t2 = same.from_model(loc, root, rot, tr)
    assert np.array_equal(r2, rot) and np.array_equal(t2, tr)


def test_elephant_fills_with_its_rig_model_and_the_vibrator_is_skipped(tmp_path, models, capfd):
    rig_from_shot(models / "elephant", ELEPHANT, "/SoC_ElephantWithMonochord/Object/Elefant/_skel")
    # 60 fps shot, keys every 30 frames over one second of it.
    opts = FillOptions(keys="1-61x30", range="1-61", out_dir=str(tmp_path / "o"), fmt="usdc")
    before = tree_hashes(ELEPHANT.parent)
    summary = validate_shot(str(ELEPHANT), opts)
    anim = "/SoC_ElephantWithMonochord/Object/Elefant/_anim"
    assert summary["models"][anim]["name"] == "elephant"
    assert [r["prim"] for r in summary["refused"]] == [
        "/SoC_ElephantWithMonochord/Object/Elefant_Monochord_Play/_skel"
    ]
    assert "train-rig" in summary["refused"][0]["reason"]
    res = fill_shot(str(ELEPHANT), opts)
    assert res["models"] == {anim: "elephant"}
    assert tree_hashes(ELEPHANT.parent) == before
    name, krot, kroot, _ = FakeRig.calls[-1]
    assert len(krot) == 3  # keys at model frames 0, 15, 30 (60 → 30 fps)
    err = capfd.readouterr().err
    assert f"{anim}: rig model elephant" in err


# --- end to end with a real (tiny) GANimator rig model -------------------------------------


def train_tiny(shot: Path, out: Path, *extra: str) -> Path:
    """`tween train-rig SHOT --out OUT --schedule tiny` (seconds on 2 cores)."""
    import os
    import subprocess
    import sys

    r = subprocess.run(
        [sys.executable, "-m", "pipeline.cli", "train-rig", str(shot), "--out", str(out), "--schedule", "tiny",
         *extra],
        capture_output=True, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"},
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-2000:]
    return out


@pytest.fixture(scope="module")
def tiny_root(tmp_path_factory):
    """A models root holding one tiny rig model trained on a 61-frame creature clip."""
    base = tmp_path_factory.mktemp("tiny")
    clip = creature_shot(base / "clip.usda", T=61, keys_every=1)
    train_tiny(clip, base / "models" / "creature")
    return base / "models"


def test_tiny_rig_model_fills_a_blocked_shot_end_to_end(tmp_path, tiny_root, monkeypatch):
    from pxr import Usd

    from pipeline.rig.store import read_rig_json

    monkeypatch.setenv("TWEEN_MODELS", str(tiny_root))
    fill._MODELS.clear()
    info = read_rig_json(tiny_root / "creature")
    shot = creature_shot(tmp_path / "sh" / "cr100.usda", T=61, keys_every=12)
    before = tree_hashes(shot.parent)
    res = fill_shot(str(shot), FillOptions(takes=2, seed=0, out_dir=str(tmp_path / "o")))
    assert res["models"] == {CREATURE_ANIM: "creature"} and res["model_hash"] == info.hash
    assert tree_hashes(shot.parent) == before
    src_stage = Usd.Stage.Open(str(shot))
    src = src_stage.GetPrimAtPath(CREATURE_ANIM)
    keys = src.GetAttribute("rotations").GetTimeSamples()
    takes = []
    for take in range(2):
        stage = Usd.Stage.Open(res["review"])
        stage.GetPrimAtPath("/World").GetVariantSet("tweenTake").SetVariantSelection(f"take{take}")
        filled = stage.GetPrimAtPath(CREATURE_ANIM + "_tween")
        assert filled.GetAttribute("tween:model").Get() == "creature"
        assert filled.GetAttribute("tween:modelHash").Get() == info.hash
        for attr in ("rotations", "translations"):
            for t in keys:
                a, b = np.array(src.GetAttribute(attr).Get(t)), np.array(filled.GetAttribute(attr).Get(t))
                assert np.array_equal(a, b), (take, attr, t)
        rot = np.array([filled.GetAttribute("rotations").Get(1001 + i) for i in range(61)])
        assert np.isfinite(rot).all() and np.allclose(np.linalg.norm(rot, axis=-1), 1, atol=1e-4)
        takes.append(rot)
    # The model generates: between keys its poses are not the keys' SLERP, and takes differ.
    from pipeline.infer.interp import interpolate_keys

    m = creature_motion(61)
    lerp = interpolate_keys(m, np.arange(0, 61, 12))
    assert np.abs(np.abs((takes[0] * lerp.rotations).sum(-1)) - 1).max() > 1e-4
    assert np.abs(takes[0] - takes[1]).max() > 1e-5


def test_tiny_rig_model_synthesises_and_scores(tiny_root):
    """The metrics on real model output: samples are finite, the clip scores itself perfectly."""
    from pipeline.rig import diversity
    from pipeline.rig.infer import RigInbetweener
    from pipeline.rig.source import load_rig_source, stored_path

    inb = RigInbetweener(tiny_root / "creature")
    clip = load_rig_source(stored_path(inb.meta["source"]["path"]))
    src = diversity.features(clip.rotations)
    sample = inb.synthesize(122, seed=1)
    assert len(sample) == 122 and sample.skeleton.names == clip.skeleton.names
    q = diversity.features(sample.rotations)
    cov = diversity.coverage(q, src)
    pnn = diversity.global_diversity(q, src)
    assert 0.0 <= cov <= 1.0 and np.isfinite(pnn.value) and pnn.value > 0
    assert diversity.coverage(src, src) == 1.0 and diversity.global_diversity(src, src).value == 0.0


def test_shipped_elephant_model_fills_the_elephant(tmp_path, monkeypatch):
    """The repository's models/elephant is picked for the elephant with no --model; the
    Vibrator (2 joints) is skipped with the train hint; keys stay the authored values."""
    from pxr import Usd

    from pipeline.rig.store import read_rig_json

    monkeypatch.delenv("TWEEN_MODELS", raising=False)
    fill._MODELS.clear()
    shipped = Path(fill.__file__).resolve().parents[2] / "models" / "elephant"
    info = read_rig_json(shipped)
    anim = "/SoC_ElephantWithMonochord/Object/Elefant/_anim"
    before = tree_hashes(ELEPHANT.parent)
    opts = FillOptions(keys="1-121x30", range="1-121", takes=2, out_dir=str(tmp_path / "o"), fmt="usdc")
    res = fill_shot(str(ELEPHANT), opts)
    assert res["models"] == {anim: info.name} and res["model_hash"] == info.hash
    assert tree_hashes(ELEPHANT.parent) == before
    src_stage = Usd.Stage.Open(str(ELEPHANT))
    src = src_stage.GetPrimAtPath(anim).GetAttribute("rotations")
    authored = [
        t for t in src.GetTimeSamples() if abs(t - round(t)) < 1e-3 and round(t) in (1, 31, 61, 91, 121)
    ]
    assert len(authored) == 5
    for take in range(2):
        stage = Usd.Stage.Open(res["review"])
        stage.GetPrimAtPath("/SoC_ElephantWithMonochord").GetVariantSet("tweenTake").SetVariantSelection(
            f"take{take}"
        )
        filled = stage.GetPrimAtPath(anim + "_tween")
        assert filled.GetAttribute("tween:model").Get() == info.name
        got = filled.GetAttribute("rotations")
        for t in authored:
            assert np.array_equal(np.array(src.Get(t)), np.array(got.Get(t))), (take, t)
        mid = np.array([got.Get(float(t)) for t in range(2, 121)])
        assert np.isfinite(mid).all()
    fill._MODELS.clear()


def test_tween_fill_cli_through_the_embedded_farm_picks_the_rig_model(tmp_path, tiny_root):
    """`tween fill` (embedded farm: a real worker process) says which model it used."""
    import os
    import subprocess
    import sys

    shot = creature_shot(tmp_path / "cr300.usda", T=31, keys_every=10)
    env = {**os.environ, "TWEEN_MODELS": str(tiny_root), "TWEEN_CACHE": str(tmp_path / "cache"),
           "TWEEN_FARM_CONFIG": os.devnull}  # fmt: skip
    env.pop("TWEEN_BROKER_URL", None)
    cmd = [
        sys.executable,
        "-m",
        "pipeline.cli",
        "fill",
        str(shot),
        "--out-dir",
        str(tmp_path / "o"),
        "--no-progress",
    ]
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip() == (
        f"{shot}: layer {tmp_path / 'o' / 'cr300.tween.v001.usda'}, review {tmp_path / 'o' / 'cr300.review.v001.usda'}, "
        "model creature"
    )


def test_a_creature_on_its_rig_model_is_not_judged_by_a_humans_bounds(tmp_path, models):
    """A key far from the next: on the creature's own rig model nothing is said (a cheetah
    outruns any sprinter); interpolated on its own rig, the human bounds flag the pair."""
    from pxr import Gf, Usd

    shot = creature_shot(tmp_path / "shots" / "cr010.usda")
    rig_from_shot(models / "creature", shot)
    stage = Usd.Stage.Open(str(shot))
    attr = stage.GetPrimAtPath(CREATURE_ANIM).GetAttribute("translations")
    tr = attr.Get(1031.0)
    tr[0] = tr[0] + Gf.Vec3f(5000.0, 0, 0)
    attr.Set(tr, 1031.0)
    stage.GetRootLayer().Save()
    res = fill_shot(str(shot), FillOptions(out_dir=str(tmp_path / "o")))
    assert res["models"] == {CREATURE_ANIM: "creature"} and res["jumps"] == {CREATURE_ANIM: []}
    res = fill_shot(str(shot), FillOptions(model="interp", out_dir=str(tmp_path / "o2")))
    assert [(j["from"], j["to"]) for j in res["jumps"][CREATURE_ANIM]] == [(1021.0, 1031.0), (1031.0, 1041.0)]
