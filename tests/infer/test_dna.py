"""Motion DNA: representative poses, their facing-free encoding (numpy and torch alike)."""

import numpy as np
import pytest

from pipeline.data.protocol import yaw_quat
from pipeline.data.skeletons import bandai_skeleton
from pipeline.infer.dna_poses import dna_poses, n_dna_channels, representative_frames
from pipeline.motion.bvh import read_bvh
from pipeline.motion.fk import fk
from pipeline.motion.rotations import quat_apply, quat_mul

SKEL = bandai_skeleton()


def test_dna_poses_ignore_where_the_reference_stands_and_faces(bandai_clip):
    m = read_bvh(bandai_clip).continuous()
    rot, root = m.rotations[::40][:6], m.root_positions[::40][:6]
    poses = dna_poses(rot, root, SKEL)
    assert poses.shape == (n_dna_channels(len(SKEL)), len(rot))
    q = yaw_quat(np.full(len(rot), 2.1))
    turned = rot.astype(np.float64).copy()
    turned[:, 0] = quat_mul(q, turned[:, 0])
    moved = quat_apply(q, root) + np.array([300.0, 0.0, -120.0])
    np.testing.assert_allclose(dna_poses(turned, moved, SKEL), poses, atol=1e-5)
    # Different poses give different encodings.
    assert np.abs(poses[:, 0] - poses[:, 1]).max() > 0.01


def test_representative_frames_are_the_fastest_turning_and_spaced(bandai_clip):
    rot = read_bvh(bandai_clip).continuous().rotations[:300]
    idx = representative_frames(rot, 5, spacing=20)
    assert len(idx) == 5 and np.all(np.diff(idx) >= 20)
    dot = np.abs((rot[:-2] * rot[2:]).sum(-1)).clip(0, 1)
    change = np.r_[0, (2 * np.arccos(dot)).sum(-1), 0]
    assert change[idx].min() > np.median(change)  # the paper's rule: frames that turn most
    within = representative_frames(rot, 3, spacing=5, frames=np.arange(100, 150))
    assert within.min() >= 100 and within.max() < 150


def test_training_pose_encoding_matches_the_farms(bandai_clip):
    torch = pytest.importorskip("torch")
    from pipeline.train.generator_training import facing_poses

    m = read_bvh(bandai_clip).continuous()
    rot, root = m.rotations[::50][:4], m.root_positions[::50][:4]
    _, pos = fk(rot.astype(np.float64), root, SKEL.parents, SKEL.offsets)
    got = facing_poses(torch.from_numpy(pos)[None], SKEL)[0].numpy()  # (R, J − 1, 3)
    want = dna_poses(rot, root, SKEL).T.reshape(len(rot), -1, 3)
    np.testing.assert_allclose(got, want, atol=1e-5)


@pytest.fixture(scope="module")
def tiny_dna_model(tmp_path_factory):
    """A small generator with a DNA encoder (its DNA map not at zero), exported to ONNX."""
    torch = pytest.importorskip("torch")
    from dataclasses import asdict

    from pipeline.networks.generator import Generator, GeneratorConfig
    from pipeline.train.export import export

    torch.manual_seed(0)
    gcfg = GeneratorConfig(width=32, levels=(32, 48, 64, 64, 64), dna=16)
    g = Generator(gcfg)
    torch.nn.init.normal_(g.out.weight, std=0.01)
    torch.nn.init.normal_(g.dna.proj.weight, std=0.5)
    run = tmp_path_factory.mktemp("dna_run")
    torch.save(
        {"model": g.state_dict(), "config": {"model": asdict(gcfg)}, "step": 0, "elapsed": 0.0},
        run / "generator.pt",
    )
    out = tmp_path_factory.mktemp("dna_model") / "tiny-dna"
    export(run, out, "tiny-dna")
    return out


def test_reference_take_reads_bvh_and_usd_and_names_a_bad_file(bandai_clip, tmp_path):
    from pipeline.errors import ShotError
    from pipeline.motion.clip import Motion
    from pipeline.usd.convert import write_shot
    from pipeline.usd.take import model_take as reference_take

    take = reference_take(bandai_clip)
    assert len(take.skeleton) == len(SKEL) and len(take) > 30
    m = read_bvh(bandai_clip).continuous().slice(0, 60)
    usd = write_shot(
        Motion(m.skeleton, m.rotations, m.root_positions, 30.0), tmp_path / "ref.usda", start=1001
    )
    again = reference_take(usd)
    assert len(again) == 60
    # The same poses, whichever way they come in (root-relative, facing-free).
    np.testing.assert_allclose(dna_poses(again.rotations[:5], again.root_positions[:5], SKEL),
                               dna_poses(take.rotations[:5], take.root_positions[:5], SKEL), atol=1e-3)  # fmt: skip
    bad = tmp_path / "notes.usda"
    bad.write_text("not usd at all")
    for path in (tmp_path / "missing.usda", bad):
        with pytest.raises(ShotError, match=str(path.name)):
            reference_take(path)


def test_fill_with_a_dna_steers_the_take_and_is_recorded(tiny_dna_model, bandai_clip, tmp_path):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parents[1]))
    from pxr import Sdf, Usd
    from usd_fixtures import FILLED, bandai_shot, samples

    from pipeline.errors import TweenError
    from pipeline.fill.api import FillOptions, fill_shot, validate_shot

    shot = bandai_shot(tmp_path / "shot.usda", frames=61, keys_every=20)
    before = Path(shot).read_bytes()
    plain = fill_shot(str(shot), FillOptions(model=str(tiny_dna_model), out_dir=str(tmp_path / "a")))
    opts = FillOptions(
        model=str(tiny_dna_model), out_dir=str(tmp_path / "b"), dna=str(bandai_clip), dna_poses=3
    )
    assert validate_shot(str(shot), opts)["dna"] == {"file": str(bandai_clip), "poses": 3}
    steered = fill_shot(str(shot), opts)
    assert Path(shot).read_bytes() == before  # the animator's file is never touched
    rot_a = samples(Usd.Stage.Open(plain["review"]), FILLED)
    rot_b = samples(Usd.Stage.Open(steered["review"]), FILLED)
    assert np.array_equal(rot_a[1001.0], rot_b[1001.0]) and np.array_equal(
        rot_a[1021.0], rot_b[1021.0]
    )  # keys
    assert not np.allclose(rot_a[1010.0], rot_b[1010.0], atol=1e-4)  # in-betweens follow the DNA
    info = Sdf.Layer.FindOrOpen(steered["layer"]).customLayerData["tween"]
    assert info["dna"]["poses"] == 3 and info["dna"]["file"].endswith(Path(bandai_clip).name)
    assert "dna" not in Sdf.Layer.FindOrOpen(plain["layer"]).customLayerData["tween"]
    # A model without a DNA encoder refuses a DNA, naming the file; nothing is written.
    with pytest.raises(TweenError, match="takes no motion DNA"):
        fill_shot(str(shot), FillOptions(model="interp", out_dir=str(tmp_path / "c"), dna=str(bandai_clip)))
    assert not (tmp_path / "c").exists() or not any((tmp_path / "c").iterdir())


def test_frozen_dna_training_leaves_every_other_weight_as_it_was(tmp_path):
    torch = pytest.importorskip("torch")
    from pipeline.networks.generator import Generator, GeneratorConfig
    from pipeline.train.generator_training import TrainConfig, train

    small = dict(width=48, levels=(48, 64, 64))
    torch.manual_seed(1)
    base = Generator(GeneratorConfig(**small)).state_dict()
    torch.save({"model": base}, tmp_path / "init.pt")
    cfg = TrainConfig(steps=12, batch=8, lengths=(64,), lr=3e-3, limit_clips=40, init=str(tmp_path / "init.pt"),
                      freeze=True, dna_prob=1.0, dna_from=0.5, model=GeneratorConfig(**small, dna=16),
                      checkpoint_minutes=100)  # fmt: skip
    train(cfg, tmp_path / "run")
    out = torch.load(tmp_path / "run" / "generator.pt", weights_only=False)["model"]
    for k, v in base.items():
        assert torch.equal(out[k], v), k
    assert out["dna.proj.weight"].abs().max() > 0  # the DNA map left its zero start
    # Continuing that model frozen trains its DNA encoder again (as a trained module now: no
    # boost); adding an adapter to it trains the adapter too. The trunk never moves.
    again = dict(cfg.__dict__, init=str(tmp_path / "run" / "generator.pt"))
    more = TrainConfig(**dict(again, partial=1.0, partial_layout="insert",
                              model=GeneratorConfig(**small, dna=16, key_adapter=True)))  # fmt: skip
    train(more, tmp_path / "more")
    got = torch.load(tmp_path / "more" / "generator.pt", weights_only=False)["model"]
    for k, v in base.items():
        assert torch.equal(got[k], v), k
    assert not torch.equal(got["dna.proj.weight"], out["dna.proj.weight"])
    lrs = torch.load(tmp_path / "more" / "generator.pt", weights_only=False)["opt"]["param_groups"]
    assert [len(g["params"]) for g in lrs] == [
        len(list(Generator(GeneratorConfig(**small, dna=16)).dna.parameters())),
        3,
    ]
    assert got["adapter.2.weight"].abs().max() > 0


def test_shipped_dna_model_steers_toward_its_dna_and_keeps_keys(bandai_clip):
    from dataclasses import replace

    from pipeline.infer.api import load_inbetweener

    inb = load_inbetweener("dna")
    assert inb.has_dna and inb.name.startswith("tween-bandai-dna")
    m = read_bvh(bandai_clip).continuous()
    shot = m.slice(0, 61)
    keys = np.array([0, 30, 60])
    ref = m.slice(61, len(m)) if len(m) > 100 else m
    idx = representative_frames(ref.rotations, 4)
    dna = replace(ref, rotations=ref.rotations[idx], root_positions=ref.root_positions[idx])
    plain, steered = inb.fill(shot, keys), inb.fill(shot, keys, dna=dna)
    assert np.array_equal(steered.rotations[keys], shot.rotations[keys])
    want = dna_poses(dna.rotations, dna.root_positions, SKEL).T.reshape(len(idx), -1, 3)

    def nearest(motion):  # eq. 11: each DNA pose to its nearest in-between frame (m, mean per joint)
        got = dna_poses(motion.rotations, motion.root_positions, SKEL).T.reshape(len(motion), -1, 3)
        return np.linalg.norm(got[None] - want[:, None], axis=-1).mean(-1).min(axis=1).mean()

    assert nearest(steered) < nearest(plain)
