"""Partial keys: some joints (or the root only) keyed at a frame, masked per joint."""

import numpy as np
import pytest

from pipeline.data.skeletons import bandai_skeleton
from pipeline.infer.features import (
    NOISE_CHANNELS,
    build_features,
    check_joint_keys,
    n_adapter_channels,
    n_input_channels,
)
from pipeline.infer.generator_onnx import OnnxInbetweener
from pipeline.infer.post import match_keys
from pipeline.motion.bvh import read_bvh
from pipeline.motion.rotations import slerp_pairs
from pipeline.train.batches import insert_partial_keys, sample_joint_keys

SKEL = bandai_skeleton()
J = len(SKEL)
J6 = J * 6


@pytest.fixture(scope="module")
def clip(bandai_clip):
    m = read_bvh(bandai_clip).continuous()
    return m.rotations[None, :90].astype(np.float32), m.root_positions[None, :90].astype(np.float32)


def _mask(n_keys, partial: dict[int, list[int]]):
    """Full keys except rows ``partial[row]``, which key only those columns (J = the root)."""
    m = np.ones((n_keys, J + 1), bool)
    for row, cols in partial.items():
        m[row] = False
        m[row, cols] = True
    return m


def test_each_joint_interpolates_between_its_own_keys(clip):
    rot, root = clip
    keys = np.array([0, 10, 20])
    mask = _mask(3, {1: [J]})  # frame 10 keys the root only
    feats, ctx = build_features(rot[:, :21], root[:, :21], keys, SKEL, joint_keys=mask)
    assert feats.shape == (1, n_input_channels(J), 21)
    crot = ctx["crot"]
    # Rotations at frame 10: halfway between keys 0 and 20, not the values stored at frame 10.
    want = slerp_pairs(crot[:, 0], crot[:, 20], np.full((1, J), 0.5))
    assert np.allclose(ctx["irot"][:, 10], want, atol=1e-6)
    assert not np.allclose(ctx["irot"][:, 10], crot[:, 10], atol=1e-3)
    # The root passes through its key at frame 10.
    assert np.allclose(ctx["iroot"][:, 10], ctx["croot"][:, 10])
    assert feats[0, 2 * (J6 + 3) + 1, 10] == 1  # frame 10 is a key frame for the schedule
    # Full masks give exactly the features of plain keys.
    plain, _ = build_features(rot[:, :21], root[:, :21], keys, SKEL)
    full, _ = build_features(rot[:, :21], root[:, :21], keys, SKEL, joint_keys=np.ones((3, J + 1), bool))
    assert np.array_equal(plain, full)
    assert plain.shape[1] == n_input_channels(J)


def test_adapter_input_is_the_full_keys_input_plus_a_side_input(clip):
    """``key_adapter``: the main channels are those of the full keys alone, bit for bit; the side
    channels carry the partial key's keyed offsets from that baseline, and are zero without one."""
    rot, root = clip
    r, t = rot[:, :41], root[:, :41]
    keys = np.array([0, 16, 40])
    mask = _mask(3, {1: [0, J]})  # frame 16 keys the hips' rotation and the root
    feats, ctx = build_features(r, t, keys, SKEL, joint_keys=mask, key_adapter=True)
    plain, pctx = build_features(r, t, np.array([0, 40]), SKEL)
    assert feats.shape == (1, n_input_channels(J, key_adapter=True), 41)
    n = plain.shape[1]
    assert np.array_equal(feats[:, :n], plain) and np.array_equal(ctx["irot"], pctx["irot"])
    side = feats[0, n:]
    assert side.shape[0] == n_adapter_channels(J)
    assert np.abs(side[6:J6, 16]).max() == 0  # unkeyed joints: no offset
    assert np.abs(side[:6, 16]).max() > 1e-3 and np.abs(side[J6 : J6 + 3, 16]).max() > 1e-3
    want = (ctx["croot"][0, 16] - ctx["iroot"][0, 16]) / 100.0
    assert np.allclose(side[J6 : J6 + 3, 30], want, atol=1e-6)  # carried to every frame
    assert side[J6 + 3, 16] == 1 and side[J6 + 3 + J, 16] == 1 and side[J6 + 4 : J6 + 3 + J, 16].sum() == 0
    near = side[-2:]  # before / after the key: 1 at it, fading away
    assert near[0, 16] == 1 and near[1, 16] == 1 and near[1, 10] == 0 and 0 < near[0, 10] < 1
    # Full keys: every side channel is zero and the main ones are the plain features.
    full, _ = build_features(r, t, keys, SKEL, joint_keys=np.ones((3, J + 1), bool), key_adapter=True)
    three, _ = build_features(r, t, keys, SKEL)
    assert np.array_equal(full[:, :n], three) and not full[:, n:].any()


def test_inserted_partial_keys_fall_inside_the_long_gaps():
    rng = np.random.default_rng(0)
    keys = np.array([0, 1, 2, 5, 30, 31, 60])
    for _ in range(50):
        k, m = insert_partial_keys(rng, keys, J)
        check_joint_keys(m, len(k), J)
        assert (np.diff(k) > 0).all() and set(keys) <= set(k.tolist())
        assert m[np.isin(k, keys)].all()  # the given keys stay full
        added = k[~m.all(axis=1)]
        assert len(added) <= 2 and all(7 <= a <= 28 or 33 <= a <= 58 for a in added)
    same, m = insert_partial_keys(rng, np.array([0, 3, 6]), J)
    assert np.array_equal(same, [0, 3, 6]) and m.all()  # no gap long enough


def test_joint_key_masks_are_checked():
    with pytest.raises(ValueError, match="first and last"):
        check_joint_keys(_mask(3, {2: [0, 1]}), 3, J)
    with pytest.raises(ValueError, match="shape"):
        check_joint_keys(np.ones((3, J), bool), 3, J)
    with pytest.raises(ValueError, match="keys nothing"):
        check_joint_keys(_mask(3, {1: []}), 3, J)


def test_match_keys_pins_only_the_keyed_joints():
    rng = np.random.default_rng(0)
    B, N = 2, 30
    rot = rng.normal(size=(B, N, J, 4))
    rot /= np.linalg.norm(rot, axis=-1, keepdims=True)
    root = rng.normal(size=(B, N, 3)) * 20
    keys = np.array([0, 12, 29])
    key_rot = rng.normal(size=(B, 3, J, 4))
    key_rot /= np.linalg.norm(key_rot, axis=-1, keepdims=True)
    key_root = rng.normal(size=(B, 3, 3)) * 20
    mask = _mask(3, {1: [2, 5, J]})  # frame 12 keys joints 2 and 5 and the root
    q, r = match_keys(rot, root, key_rot.astype(np.float32), key_root.astype(np.float32), keys, mask)
    assert np.array_equal(q[:, [0, 29]], key_rot[:, [0, 2]].astype(np.float32))
    assert np.array_equal(q[:, 12, [2, 5]], key_rot[:, 1, [2, 5]].astype(np.float32))
    assert np.array_equal(r[:, 12], key_root[:, 1].astype(np.float32))
    # Joint 3 is free at frame 12: neither the stored key value nor anything pinned there.
    assert not np.allclose(np.abs((q[:, 12, 3] * key_rot[:, 1, 3]).sum(-1)), 1.0, atol=1e-3)


def test_fill_ignores_the_values_of_unkeyed_joints(clip):
    rot, root = clip
    keys = np.array([0, 1, 2, 30, 60, 89])
    mask = _mask(len(keys), {3: [J], 4: list(range(12))})  # root-only key; a key on 12 joints
    model = OnnxInbetweener("models/default")
    outs = []
    for seed in (1, 2):  # different garbage where nothing is keyed
        r, p = rot.copy(), root.copy()
        g = np.random.default_rng(seed)
        r[0, 30] = np.roll(r[0, 30], seed, axis=0)
        r[0, 60, 12:] = np.roll(r[0, 60, 12:], seed, axis=0)
        p[0, 60] += g.normal(size=3) * 50
        outs.append(model.fill_batch(r, p, keys, joint_keys=mask))
    (q1, p1), (q2, p2) = outs
    assert np.array_equal(q1, q2) and np.array_equal(p1, p2)
    assert np.array_equal(p1[0, 30], root[0, 30])  # the root key holds
    assert np.array_equal(q1[0, 60, :12], rot[0, 60, :12])  # the keyed joints hold
    assert np.array_equal(q1[0, keys[[0, 1, 2, 5]]], rot[0, keys[[0, 1, 2, 5]]])
    assert np.isfinite(q1).all() and np.isfinite(p1).all()


def test_sampled_masks_keep_first_and_last_keys_full():
    rng = np.random.default_rng(3)
    seen = set()
    for _ in range(50):
        m = sample_joint_keys(rng, 6, J, share=0.8)
        check_joint_keys(m, 6, J)
        seen.update(tuple(row) for row in m[1:-1] if not row.all())
    assert len(seen) > 3  # several kinds of partial keys


def test_partial_key_input_starts_as_its_init_and_full_keys_never_reach_it():
    """The adapter's side input, added to trained weights: zero at the start, and once trained
    still nothing for full keys (their side channels are zero)."""
    torch = pytest.importorskip("torch")
    from pipeline.networks.generator import Generator, GeneratorConfig

    torch.manual_seed(0)
    cfg = GeneratorConfig(width=32, levels=(32, 48, 64))
    old = Generator(cfg).eval()
    torch.nn.init.normal_(old.out.weight, std=0.01)
    new = Generator(GeneratorConfig(width=32, levels=(32, 48, 64), key_adapter=True)).eval()
    new.load_state_dict({**new.state_dict(), **old.state_dict()})  # as `tween train --init`
    x = torch.randn(2, n_input_channels(J), 32)
    extra = torch.randn(2, n_adapter_channels(J), 32)
    module = new.adapter
    with torch.no_grad():
        assert torch.equal(old(x), new(torch.cat([x, extra], 1)))  # the new input starts at zero
        for w in module.parameters():
            torch.nn.init.normal_(w, std=0.5)
        assert not torch.equal(old(x), new(torch.cat([x, extra], 1)))
        assert torch.equal(old(x), new(torch.cat([x, torch.zeros_like(extra)], 1)))  # full keys


def test_partial_keys_do_not_touch_the_noise_channels(clip):
    rot, root = clip
    keys = np.array([0, 10, 20])
    noise = np.ones((1, NOISE_CHANNELS))
    a, _ = build_features(rot[:, :21], root[:, :21], keys, SKEL, noise, joint_keys=_mask(3, {1: [0]}))
    assert np.allclose(a[0, -NOISE_CHANNELS:], 1.0)


def test_usd_rotations_and_translations_sampled_apart_are_partial_keys(tmp_path):
    """Translations keyed where rotations are not (and the other way round): each is kept
    where authored, and the fill supplies the other channel there (not USD's interpolation)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parents[1]))
    from pxr import Usd
    from usd_fixtures import ANIM, FILLED, bandai_shot, samples

    from pipeline.fill.api import FillOptions, fill_shot

    shot = bandai_shot(tmp_path / "apart.usda", frames=61, keys_every=5)
    stage = Usd.Stage.Open(str(shot))
    anim = stage.GetPrimAtPath(ANIM)
    rot_only = [1011.0, 1031.0, 1051.0]
    trans_only = [1006.0, 1026.0, 1046.0]
    for t in anim.GetAttribute("rotations").GetTimeSamples():
        if t in trans_only or t not in (1001.0, 1061.0, *rot_only):
            anim.GetAttribute("rotations").ClearAtTime(t)
    for t in anim.GetAttribute("translations").GetTimeSamples():
        if t in rot_only or t not in (1001.0, 1061.0, *trans_only):
            anim.GetAttribute("translations").ClearAtTime(t)
    stage.GetRootLayer().Save()
    src_rot, src_tr = samples(stage, ANIM), samples(stage, ANIM, "translations")
    usd_rot = {t: np.array(anim.GetAttribute("rotations").Get(t)) for t in trans_only}
    usd_tr = {t: np.array(anim.GetAttribute("translations").Get(t)) for t in rot_only}

    res = fill_shot(str(shot), FillOptions(out_dir=str(tmp_path / "out")))
    review = Usd.Stage.Open(res["review"])
    rot, tr = samples(review, FILLED), samples(review, FILLED, "translations")
    for t in rot_only:
        assert np.array_equal(rot[t], src_rot[t])  # the authored rotations
        assert not np.allclose(tr[t][0], usd_tr[t][0], atol=1e-3)  # the fill's root
    for t in trans_only:
        assert np.array_equal(tr[t], src_tr[t])  # the authored translations
        assert not np.allclose(rot[t], usd_rot[t], atol=1e-4)  # the fill's pose
    for t in (1001.0, 1061.0):
        assert np.array_equal(rot[t], src_rot[t]) and np.array_equal(tr[t], src_tr[t])


def _shot_with_keyed_joints(tmp_path, keyed: dict[float, list[str]]):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parents[1]))
    from pxr import Sdf, Usd, Vt
    from usd_fixtures import ANIM, bandai_shot

    shot = bandai_shot(tmp_path / "keyed.usda", frames=61, keys_every=10)
    stage = Usd.Stage.Open(str(shot))
    anim = stage.GetPrimAtPath(ANIM)
    tokens = list(anim.GetAttribute("joints").Get())
    attr = anim.CreateAttribute("tween:keyedJoints", Sdf.ValueTypeNames.TokenArray)
    for t, names in keyed.items():
        attr.Set(Vt.TokenArray([x for x in tokens if x.rsplit("/", 1)[-1] in names]), t)
    stage.GetRootLayer().Save()
    return shot, tokens


def test_usd_keyed_joints_make_per_joint_partial_keys(tmp_path):
    """tween:keyedJoints at a key names the joints it keys: they keep their authored
    rotations there, the other joints are filled, and the mask reaches the model as such."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parents[1]))
    from pxr import Usd
    from usd_fixtures import ANIM, FILLED, samples

    from pipeline.fill.api import FillOptions, fill_shot
    from pipeline.fill.plan import make_plan
    from pipeline.fill.solve import key_channels, rig_key_channels

    legs = [n for n in SKEL.names if "Leg" in n or "Foot" in n or "Toes" in n]
    shot, tokens = _shot_with_keyed_joints(tmp_path, {1031.0: ["Hips", *legs], 1041.0: []})
    before = shot.read_bytes()
    cp = make_plan(str(shot), None, None, None, 30.0).chars[0]
    mask = key_channels(cp, rig_key_channels(cp))
    k = list(cp.keys)
    row, empty = mask[k.index(1031.0)], mask[k.index(1041.0)]
    keyed = {SKEL.names[j] for j in np.flatnonzero(row[:J])}
    assert keyed == {"Hips", *legs} and row[J]  # the root position: translations are sampled
    assert not empty[:J].any() and empty[J]  # no joint: a root-only key
    assert mask[[0, 1, 2, -1]].all()

    src = samples(Usd.Stage.Open(str(shot)), ANIM)
    res = fill_shot(str(shot), FillOptions(out_dir=str(tmp_path / "out")))
    rot = samples(Usd.Stage.Open(res["review"]), FILLED)
    anim_names = [t.rsplit("/", 1)[-1] for t in tokens]
    leg_cols = [anim_names.index(n) for n in legs]
    arm = anim_names.index("LowerArm_L")
    assert np.array_equal(rot[1031.0][leg_cols], src[1031.0][leg_cols])  # keyed: authored, bitwise
    assert not np.allclose(rot[1031.0][arm], src[1031.0][arm], atol=1e-4)  # unkeyed: filled
    assert np.array_equal(rot[1021.0], src[1021.0])  # full keys stay full
    assert shot.read_bytes() == before


def test_usd_keyed_joints_naming_an_unknown_joint_is_refused(tmp_path):
    from pxr import Usd

    from pipeline.errors import ShotError
    from pipeline.usd.read import read_shot

    shot, _ = _shot_with_keyed_joints(tmp_path, {1031.0: ["Hips"]})
    stage = Usd.Stage.Open(str(shot))
    attr = stage.GetPrimAtPath("/World/Character/Skel/Anim").GetAttribute("tween:keyedJoints")
    attr.Set(["Hips/Tail"], 1031.0)
    stage.GetRootLayer().Save()
    with pytest.raises(ShotError, match=r"keyed\.usda.*tween:keyedJoints at time 1031 names 'Hips/Tail'"):
        read_shot(shot)


def test_retarget_keys_a_model_joint_only_when_every_rig_joint_it_reads_is_keyed(tmp_path):
    """On a rig unlike the model's (CMU, 100 joints), a model joint's rotation comes from a
    chain of rig joints: leaving any of them unkeyed leaves that model joint unkeyed."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parents[1]))
    from usd_fixtures import cmu_shot

    from pipeline.adapt.retarget import MODEL_JOINTS
    from pipeline.fill.plan import make_plan

    cp = make_plan(str(cmu_shot(tmp_path / "cmu.usda")), None, None, None, 30.0).chars[0]
    rt, parents = cp.retarget, cp.char.parents
    n = len(parents)
    full = rt.model_channels(np.ones((1, n), bool), np.ones(1, bool))
    assert full.all()
    arm = rt.roles["LowerArm_L"]
    rows = np.ones((3, n), bool)
    rows[0, arm] = False  # one rig joint
    rows[1, parents[rt.roles["Hips"]] if parents[rt.roles["Hips"]] >= 0 else rt.roles["Hips"]] = False
    rows[2] = False  # no rotation at all, translations keyed
    got = rt.model_channels(rows, np.array([True, True, True]))
    unkeyed0 = {MODEL_JOINTS[j] for j in np.flatnonzero(~got[0, :-1])}
    assert unkeyed0 == {"LowerArm_L"} and got[0, -1]
    assert not got[1, MODEL_JOINTS.index("Hips")]
    assert not got[2, :-1].any()
    assert rt.model_channels(np.ones((1, n), bool), np.zeros(1, bool))[0, -1] == 0


def test_training_matches_partial_keys_as_the_farm_does():
    """keymatch.match_partial_keys (torch, in the losses) gives post.match_keys' output where
    full keys need no correction, hits the keyed channels, and has finite gradients when a
    keyed channel is already exact."""
    torch = pytest.importorskip("torch")
    from pipeline.train.keymatch import match_partial_keys, partial_match_weights

    rng = np.random.default_rng(0)
    N, keys = 40, np.array([0, 10, 20, 39])
    jk = _mask(4, {1: [J], 2: [0, 1, 2, 3, 4]})
    q = rng.normal(size=(2, N, J, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    r = rng.normal(size=(2, N, 3))
    kq, kr = q[:, keys].copy(), r[:, keys].copy()
    kq[:, 2, :5] = rng.normal(size=(2, 5, 4))
    kq /= np.linalg.norm(kq, axis=-1, keepdims=True)
    kr[:, 1] += rng.normal(size=(2, 3))
    w = partial_match_weights(N, keys, jk)
    tq, tr = match_partial_keys(
        *(torch.tensor(a) for a in (q, r, kq, kr, keys)), torch.tensor(w, dtype=torch.float64)
    )
    mq, mr = match_keys(q, r, kq, kr, keys, jk)
    assert np.allclose(np.abs((tq.numpy() * mq).sum(-1)), 1.0, atol=1e-6)
    assert np.allclose(tr.numpy(), mr, atol=1e-6)
    assert np.allclose(tr.numpy()[:, 10], kr[:, 1])
    # Already exact: the correction is zero and its gradient finite.
    qt = torch.tensor(q, requires_grad=True)
    out, _ = match_partial_keys(
        qt,
        torch.tensor(r),
        torch.tensor(q[:, keys]),
        torch.tensor(r[:, keys]),
        torch.tensor(keys),
        torch.tensor(w, dtype=torch.float64),
    )
    out.sum().backward()
    assert torch.isfinite(qt.grad).all() and torch.allclose(out, qt.detach())


def test_shipped_model_reads_partial_keys_through_its_adapter(clip):
    """The default takes partial keys into the network (its adapter), not only by matching
    afterwards: the fill differs from the full-keys fill matched to the partial key, stays close
    to it (the adapter starts as that fallback and was trained from there), and keys hold."""
    rot, root = clip
    model = OnnxInbetweener("models/default")
    assert model.meta["generator"]["key_adapter"]
    model.feet = False  # compare the networks' output, before the foot lock
    keys = np.array([0, 1, 2, 30, 60, 89])
    mask = _mask(len(keys), {3: [J], 4: list(range(12))})
    q, p = model.fill_batch(rot, root, keys, joint_keys=mask)
    full = mask.all(axis=1)
    fq, fp, _ = model.raw(rot, root, keys[full], None, None, None)
    fq, fp = match_keys(fq, fp, rot[:, keys], root[:, keys], keys, mask)
    assert np.array_equal(p[0, 30], root[0, 30]) and np.array_equal(q[0, 60, :12], rot[0, 60, :12])
    moved = np.abs(p - fp).max()
    assert 1e-3 < moved < 10.0, moved  # cm: the adapter's own contribution, small
    turned = np.degrees(2 * np.arccos(np.clip(np.abs((q * fq).sum(-1)), 0, 1))).max()
    assert 1e-3 < turned < 20.0, turned
