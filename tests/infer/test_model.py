"""The in-betweener: dense key format, networks, post-processing, ONNX export, a tiny training run."""

import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from pipeline.data.skeletons import LEGS, bandai_skeleton
from pipeline.infer.features import build_features, key_neighbours, n_input_channels, n_output_channels
from pipeline.infer.post import lock_feet, match_keys, two_bone_ik
from pipeline.motion.bvh import read_bvh
from pipeline.motion.fk import fk

torch = pytest.importorskip("torch")
SKEL = bandai_skeleton()
RNG = np.random.default_rng(0)


def bone_lengths(p):
    """(N, J − 1) bone lengths of (N, J, 3) joint positions."""
    return np.linalg.norm(p[:, 1:] - p[:, SKEL.parents[1:]], axis=-1)


def random_motion(B, N, J=21, seed=0):
    rot = Rotation.random(B * N * J, random_state=seed).as_quat().reshape(B, N, J, 4).astype(np.float32)
    root = RNG.normal(scale=30, size=(B, N, 3)).astype(np.float32)
    return rot, root


def test_key_neighbours_and_dense_format_on_hand_made_keys():
    keys = np.array([3, 8, 10])
    prev, nxt = key_neighbours(13, keys)
    assert prev.tolist() == [3, 3, 3, 3, 3, 3, 3, 3, 8, 8, 10, 10, 10]
    assert nxt.tolist() == [3, 3, 3, 3, 8, 8, 8, 8, 8, 10, 10, 10, 10]
    rot, root = random_motion(1, 13)
    feats, ctx = build_features(rot, root, keys, SKEL)
    assert feats.shape == (1, n_input_channels(21), 13)
    J6 = 21 * 6
    dense = feats[0, J6 + 3 : 2 * J6 + 3]  # nearest-key pose channels
    dist = feats[0, 2 * J6 + 6] * 30  # distance-to-key channel, in frames
    assert np.allclose(dist, [3, 2, 1, 0, 1, 2, 2, 1, 0, 1, 0, 1, 2])
    # Frames 5 (nearer 3? no: 2 from 3, 3 from 8) and 6 (3 from 3, 2 from 8) copy different keys.
    assert np.allclose(dense[:, 5], dense[:, 3]) and np.allclose(dense[:, 6], dense[:, 8])
    is_key = feats[0, 2 * J6 + 7]
    assert is_key.tolist() == [float(i in (3, 8, 10)) for i in range(13)]
    # Baseline channels equal the keys' own (canonical) pose at key frames.
    assert np.allclose(feats[0, :J6, 8], feats[0, J6 + 3 : 2 * J6 + 3, 8], atol=1e-5)


def test_canonical_frame_puts_first_key_at_origin_facing_x():
    m = read_bvh(__import__("pipeline.data.split", fromlist=["x"]).list_clips("eval")[1]).continuous()
    assert len(m) > 41
    keys = np.array([0, 20, 40])
    _, ctx = build_features(m.rotations[None, :41], m.root_positions[None, :41], keys, SKEL)
    assert np.allclose(ctx["croot"][0, 0, [0, 2]], 0, atol=1e-4)
    from pipeline.data.protocol import facing

    _, pos = fk(ctx["crot"][:, 0], ctx["croot"][:, 0], SKEL.parents, SKEL.offsets)
    assert np.allclose(facing(pos, SKEL)[0], [1, 0, 0], atol=1e-5)


def test_generator_and_path_shapes():
    from pipeline.networks.generator import Generator, GeneratorConfig
    from pipeline.networks.path import PathConfig, PathPredictor

    cfg = GeneratorConfig(width=32, levels=(32, 48, 64))
    g = Generator(cfg)
    x = torch.randn(2, n_input_channels(21), 5 * cfg.multiple)
    assert g(x).shape == (2, n_output_channels(21), 5 * cfg.multiple)
    assert cfg.receptive_field() == 1 + 3 * (1 + 2 + 4) + 2 * 8 * (1 + 2)
    p = PathPredictor(PathConfig(channels=(16, 24)))
    assert p(torch.randn(3, 60, 64)).shape == (3, 3, 64)


def test_match_keys_exact_and_smooth_for_random_inputs():
    B, N = 2, 40
    rot, root = random_motion(B, N, seed=1)
    rot = np.cumsum(RNG.normal(scale=0.02, size=(B, N, 21, 4)), axis=1) + np.array([0, 0, 0, 1.0])
    rot = (rot / np.linalg.norm(rot, axis=-1, keepdims=True)).astype(np.float32)
    keys = np.array([2, 11, 25, 39])
    key_rot, key_root = random_motion(B, len(keys), seed=2)
    key_rot = (rot[:, keys] + RNG.normal(scale=0.05, size=(B, 4, 21, 4))).astype(np.float32)
    key_rot /= np.linalg.norm(key_rot, axis=-1, keepdims=True)
    key_root = (root[:, keys] + RNG.normal(scale=5, size=(B, 4, 3))).astype(np.float32)
    out_r, out_p = match_keys(rot, root, key_rot, key_root, keys)
    assert np.array_equal(out_r[:, keys], key_rot) and np.array_equal(out_p[:, keys], key_root)
    # No pop: the correction changes slowly near keys (smoothstep has zero slope at keys).
    corr = out_p - root
    step = np.abs(np.diff(corr, axis=1))
    jump_at_keys = np.abs(key_root - root[:, keys]).max()
    assert step[:, 2:38].max() < 0.5 * jump_at_keys
    assert np.array_equal(out_p[:, :2], np.repeat(key_root[:, :1], 2, 1))  # held before the first key


def test_two_bone_ik_keeps_bone_lengths_and_reaches_target(bandai_clip):
    m = read_bvh(bandai_clip)
    rot, root = m.rotations[:20], m.root_positions[:20]
    leg = tuple(SKEL.index(n) for n in LEGS[0])
    _, pos = fk(rot, root, SKEL.parents, SKEL.offsets)
    target = pos[:, leg[2]] + np.array([4.0, 3.0, -2.0])
    out = two_bone_ik(rot, root, SKEL, leg, target, np.ones(20))
    _, new = fk(out, root, SKEL.parents, SKEL.offsets)
    np.testing.assert_allclose(new[:, leg[2]], target, atol=1e-2)
    np.testing.assert_allclose(bone_lengths(new), bone_lengths(pos), atol=1e-3)
    # The other leg and the upper body did not move.
    other = [SKEL.index(n) for n in LEGS[1]] + [SKEL.index("Head")]
    np.testing.assert_allclose(new[:, other], pos[:, other], atol=1e-4)


def test_lock_feet_reduces_slide_and_keeps_keys(bandai_clip):
    m = read_bvh(bandai_clip)
    rot, root = m.rotations[:30].copy(), m.root_positions[:30].copy()
    root[:, 0] += np.linspace(0, 15, 30)  # make the whole body (and feet) slide
    legs = [tuple(SKEL.index(n) for n in leg) for leg in LEGS]
    contacts = np.ones((30, 2))
    keys = np.array([0, 29])
    out = lock_feet(rot, root, SKEL, contacts, keys, legs)
    _, before = fk(rot, root, SKEL.parents, SKEL.offsets)
    _, after = fk(out, root, SKEL.parents, SKEL.offsets)
    ankle = legs[0][2]
    slide = lambda p: np.linalg.norm(np.diff(p[8:22, ankle][:, [0, 2]], axis=0), axis=-1).mean()  # noqa: E731
    assert slide(after) < 0.5 * slide(before)
    assert np.array_equal(out[keys], rot[keys])


def test_anchored_feet_stay_where_the_key_planted_them(bandai_clip):
    m = read_bvh(bandai_clip)
    rot, root = m.rotations[:12].copy(), m.root_positions[:12].copy()
    root[:, 0] += np.linspace(0, 6, 12)  # a 5-frame gap whose feet slide: shorter than the fade
    legs = [tuple(SKEL.index(n) for n in leg) for leg in LEGS]
    contacts = np.zeros((12, 2))
    contacts[2:9] = 1.0  # one contact per leg, holding key 4 (and reaching past key 8)
    keys = np.array([0, 1, 2, 3, 4, 10])
    ankle = legs[0][2]
    _, before = fk(rot, root, SKEL.parents, SKEL.offsets)
    plain = lock_feet(rot, root, SKEL, contacts, keys, legs)
    out = lock_feet(rot, root, SKEL, contacts, keys, legs, anchor=True)
    _, after = fk(out, root, SKEL.parents, SKEL.offsets)
    _, after_plain = fk(plain, root, SKEL.parents, SKEL.offsets)
    drift = lambda p: np.linalg.norm(p[5:9, ankle, [0, 2]] - p[4, ankle, [0, 2]], axis=-1)  # noqa: E731
    assert drift(after)[0] < 0.05  # full weight right after the key (then the contact's ramp out)
    held = lambda p: drift(p)[:3].mean()  # noqa: E731  (frame 8 is the contact's last)
    assert held(after) < 0.5 * held(after_plain) and held(after) < 0.5 * held(before)
    assert np.array_equal(out[keys], rot[keys])
    assert np.array_equal(out[11:], rot[11:])  # held frames after the last key: untouched
    _, gp_before = fk(rot, root, SKEL.parents, SKEL.offsets)
    assert np.abs(bone_lengths(after) - bone_lengths(gp_before)).max() < 1e-4


def test_two_bone_ik_turns_the_foot_to_a_given_orientation(bandai_clip):
    m = read_bvh(bandai_clip)
    rot, root = m.rotations[:20], m.root_positions[:20]
    leg = tuple(SKEL.index(n) for n in LEGS[0])
    gq, pos = fk(rot, root, SKEL.parents, SKEL.offsets)
    target = pos[:, leg[2]] + np.array([2.0, 1.0, -1.0])
    orient = np.repeat(gq[5:6, leg[2]], 20, axis=0)  # frame 5's foot orientation everywhere
    weight = np.r_[np.ones(10), np.zeros(10)]
    out = two_bone_ik(rot, root, SKEL, leg, target, weight, orient)
    gq_new, new = fk(out, root, SKEL.parents, SKEL.offsets)
    turned = Rotation.from_quat(gq_new[:10, leg[2]]).inv() * Rotation.from_quat(orient[:10])
    assert np.degrees(turned.magnitude()).max() < 0.1
    np.testing.assert_allclose(new[:10, leg[2]], target[:10], atol=1e-2)
    np.testing.assert_allclose(out[10:], rot[10:])  # weight 0: untouched
    np.testing.assert_allclose(bone_lengths(new), bone_lengths(pos), atol=1e-3)


def test_locked_feet_holding_their_orientation_keep_the_toes_still(bandai_clip):
    m = read_bvh(bandai_clip)
    rot, root = m.rotations[:30].copy(), m.root_positions[:30].copy()
    root[:, 0] += np.linspace(0, 10, 30)
    legs = [tuple(SKEL.index(n) for n in leg) for leg in LEGS]
    ankle, toe = legs[0][2], legs[0][3]
    # The foot pitches through 40 degrees while in contact: the ankle lock alone lets the toes slide.
    pitch = Rotation.from_euler("x", np.linspace(0, 40, 30)[:, None], degrees=True)
    rot[:, ankle] = (Rotation.from_quat(rot[:, ankle]) * pitch).as_quat()
    contacts = np.ones((30, 2))
    keys = np.array([0, 29])
    plain = lock_feet(rot, root, SKEL, contacts, keys, legs)
    held = lock_feet(rot, root, SKEL, contacts, keys, legs, orient=True)

    def slide(r):
        toes = fk(r, root, SKEL.parents, SKEL.offsets)[1][8:22, toe]
        return np.linalg.norm(np.diff(toes[:, [0, 2]], axis=0), axis=-1).mean()

    assert slide(held) < 0.3 * slide(plain)
    assert np.array_equal(held[keys], rot[keys])
    _, before = fk(rot, root, SKEL.parents, SKEL.offsets)
    _, after = fk(held, root, SKEL.parents, SKEL.offsets)
    assert np.abs(bone_lengths(after) - bone_lengths(before)).max() < 1e-4
    # Anchored: between two keys holding the contact, the foot turns evenly from one key's
    # orientation to the other's, and both keys stay exact.
    anchored = lock_feet(rot, root, SKEL, contacts, keys, legs, anchor=True, orient=True)
    assert np.array_equal(anchored[keys], rot[keys])
    gq_a, _ = fk(anchored, root, SKEL.parents, SKEL.offsets)
    gq_0, _ = fk(rot, root, SKEL.parents, SKEL.offsets)
    at_keys = Slerp([0, 29], Rotation.from_quat(gq_0[[0, 29], ankle]))(np.arange(8, 22))
    off = at_keys.inv() * Rotation.from_quat(gq_a[8:22, ankle])
    assert np.degrees(off.magnitude()).max() < 0.1


@pytest.mark.parametrize("dna, adapter", [(0, False), (16, False), (0, True)])
def test_onnx_matches_torch_and_fill_is_exact_at_keys(tmp_path, bandai_clip, dna, adapter):
    from dataclasses import asdict

    from pipeline.infer.generator_onnx import OnnxInbetweener
    from pipeline.networks.generator import Generator, GeneratorConfig
    from pipeline.networks.path import PathConfig, PathPredictor
    from pipeline.train.export import export, verify

    torch.manual_seed(0)
    gcfg = GeneratorConfig(
        width=32,
        levels=(32, 48, 64, 64, 64),
        dna=dna,
        key_adapter=adapter,
    )
    g = Generator(gcfg)
    torch.nn.init.normal_(g.out.weight, std=0.01)  # not the zero start: a real residual
    if adapter:
        torch.nn.init.normal_(g.adapter[2].weight, std=0.1)
    if dna:
        torch.nn.init.normal_(g.dna.proj.weight, std=0.5)  # nor the DNA's
    pcfg = PathConfig(channels=(16, 24))
    run = tmp_path / "run"
    run.mkdir()
    torch.save(
        {"model": g.state_dict(), "config": {"model": asdict(gcfg)}, "step": 0, "elapsed": 0.0},
        run / "generator.pt",
    )
    torch.save(
        {"model": PathPredictor(pcfg).state_dict(), "config": {"model": asdict(pcfg)}, "step": 0},
        run / "path.pt",
    )
    meta = export(run, tmp_path / "model", "tiny")
    assert set(meta["files"]) == {"generator", "path"}
    # The train split's pose bank beside the networks, as the shipped default has it.
    assert meta["pose_bank"] == "pose_bank.npz"
    bank = OnnxInbetweener(tmp_path / "model").pose_bank
    assert np.array_equal(bank, OnnxInbetweener("models/default").pose_bank)
    assert verify(run, tmp_path / "model") < 1e-4
    m = read_bvh(bandai_clip).continuous().slice(0, 70)
    keys = np.array([0, 1, 2, 20, 45, 69])
    out = OnnxInbetweener(tmp_path / "model").fill(m, keys)
    assert np.array_equal(out.rotations[keys], m.rotations[keys])
    assert np.array_equal(out.root_positions[keys], m.root_positions[keys])
    assert len(out) == 70 and np.isfinite(out.rotations).all()
    assert meta["generator"]["key_adapter"] == adapter
    if adapter:  # partial keys: the root only at frame 20, and they reach the network
        jk = np.ones((len(keys), 22), bool)
        jk[3, :21] = False
        inb = OnnxInbetweener(tmp_path / "model")
        out = inb.fill(m, keys, joint_keys=jk)
        assert np.array_equal(out.root_positions[20], m.root_positions[20])
        assert not np.array_equal(out.rotations[20], m.rotations[20])
        assert not np.array_equal(out.rotations, inb.fill(m, keys).rotations)
    inb = OnnxInbetweener(tmp_path / "model")
    ref = read_bvh(bandai_clip).continuous()
    poses = ref.slice(200, 300)
    poses = replace(poses, rotations=poses.rotations[::30], root_positions=poses.root_positions[::30])
    if dna:  # a DNA changes the in-betweens, never the keys; the same DNA, the same fill
        plain, steered = inb.fill(m, keys), inb.fill(m, keys, dna=poses)
        assert np.array_equal(steered.rotations[keys], m.rotations[keys])
        assert not np.allclose(steered.rotations, plain.rotations, atol=1e-4)
        assert np.array_equal(steered.rotations, inb.fill(m, keys, dna=poses).rotations)
    else:
        with pytest.raises(ValueError, match="motion-DNA"):
            inb.fill(m, keys, dna=poses)


@pytest.mark.parametrize(  # partial: the adapter with inserted partial keys
    "partial, dna, adapter", [(0.0, 0, False), (0.0, 16, False), (1.0, 0, True)]
)
def test_tiny_training_run_loss_falls(tmp_path, partial, dna, adapter):
    from pipeline.networks.generator import GeneratorConfig
    from pipeline.train.generator_training import TrainConfig, train

    cfg = TrainConfig(
        steps=60,
        batch=8,
        lengths=(64,),
        lr=3e-3,
        limit_clips=40,
        partial=partial,
        partial_layout="insert" if adapter else "convert",
        model=GeneratorConfig(
            width=48,
            levels=(48, 64, 64),
            key_adapter=adapter,
            dna=dna,
        ),
        checkpoint_minutes=100,
    )
    train(cfg, tmp_path)
    log = [json.loads(line) for line in (tmp_path / "train_log.jsonl").read_text().splitlines()]
    assert log[-1]["pos"] < log[0]["pos"] and log[-1]["loss"] < log[0]["loss"]
    if dna:  # the DNA term is on: some windows have poses to place
        assert all(np.isfinite(r["dna"]) for r in log) and max(r["dna"] for r in log) > 0
    assert (tmp_path / "generator.pt").exists()


def test_filling_does_not_import_torch(bandai_clip):
    code = (
        "import sys, numpy as np\n"
        "from pipeline.infer import load_inbetweener\n"
        "from pipeline.motion.bvh import read_bvh\n"
        f"m = read_bvh({str(bandai_clip)!r}).continuous().slice(0, 64)\n"
        "inb = load_inbetweener('default')\n"
        "out = inb.fill(m, np.array([0, 30, 63]))\n"
        "assert 'torch' not in sys.modules, 'torch imported'\n"
        "print(inb.name)\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr


def test_shipped_model_takes_deterministic_and_distinct(bandai_clip):
    from pipeline.infer.api import load_inbetweener

    inb = load_inbetweener("default")
    assert inb.name != "interpolation", "no shipped model in models/default"
    m = read_bvh(bandai_clip).continuous().slice(0, 96)
    keys = np.array([0, 30, 60, 95])
    a = inb.fill(m, keys, seed=3)
    b = inb.fill(m, keys, seed=3)
    c = inb.fill(m, keys, seed=4)
    assert np.array_equal(a.rotations, b.rotations) and np.array_equal(a.root_positions, b.root_positions)
    assert not np.array_equal(a.rotations, c.rotations)  # another seed, another take
    for out in (a, c):
        assert np.array_equal(out.rotations[keys], m.rotations[keys])
        assert np.array_equal(out.root_positions[keys], m.root_positions[keys])
    # A learned fill, not the interpolation baseline.
    from pipeline.infer.interp import interpolate_keys

    assert not np.allclose(a.positions(), interpolate_keys(m, keys).positions(), atol=1e-3)


def test_export_check_is_relative_only_for_random_inputs():
    """Random features drive outputs to ±100, where float32 alone rounds at ~1e-5; real
    features are compared absolutely."""
    from pipeline.train.export import _gap

    a, b = np.array([100.0, 0.5]), np.array([100.004, 0.5])
    assert abs(_gap(a, b, random=True) - 0.004 / 100.004) < 1e-12
    assert abs(_gap(a, b, random=False) - 0.004) < 1e-12
    assert abs(_gap(np.array([0.2]), np.array([0.3]), random=True) - 0.1) < 1e-12  # |b| < 1: absolute
