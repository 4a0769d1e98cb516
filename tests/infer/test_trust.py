"""The trusted fill (pipeline/infer/trust.py): probes from the keys, the decision, overrides,
blends, exact keys, JSON decisions and the cost bound."""

import json
import shutil
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pipeline.data.protocol import yaw_quat
from pipeline.data.skeletons import bandai_skeleton
from pipeline.fill.api import trust_line
from pipeline.infer import novelty, trust
from pipeline.infer.api import Capabilities
from pipeline.infer.folder import ModelFolderError
from pipeline.infer.generator_onnx import OnnxInbetweener
from pipeline.infer.spline import SplineInbetweener
from pipeline.motion.augment import posture_offsets
from pipeline.motion.bvh import read_bvh
from pipeline.motion.clip import Motion
from pipeline.motion.rotations import quat_mul

SKEL = bandai_skeleton()
PROTOCOL_KEYS = np.r_[np.arange(10), 40]  # 10 context frames, a 30-frame transition


class StandIn:
    """A model stand-in with the batch interface; counts its calls and the frames it fills.

    ``mode``: "oracle" returns its input (the test passes the true motion in every frame, so
    it is exact at the left-out keys); "noise" returns random poses between the keys."""

    name, model_hash, fps = "stand-in", "stand-in-hash", 30.0
    capabilities = Capabilities(partial_keys=True, dna=False, batch=True, any_rig=False)

    def __init__(self, mode: str, seed: int = 0):
        self.mode, self.skeleton = mode, SKEL
        self.rng = np.random.default_rng(seed)
        self.calls, self.frames = 0, []

    def fill_batch(self, rot, root, keys):
        self.calls += 1
        self.frames.append(rot.shape[1])
        rot, root = np.array(rot), np.array(root)
        if self.mode == "nan":  # a broken network (a damaged export): NaN between the keys
            rot[:, np.setdiff1d(np.arange(rot.shape[1]), keys)] = np.nan
        if self.mode == "noise":
            free = np.setdiff1d(np.arange(rot.shape[1]), keys)
            n = rot.shape[0] * len(free) * rot.shape[2]
            q = Rotation.random(n, random_state=int(self.rng.integers(1 << 31))).as_quat()
            rot[:, free] = q.reshape(rot.shape[0], len(free), rot.shape[2], 4)
            root[:, free] += self.rng.normal(scale=20.0, size=root[:, free].shape)
        return rot.astype(np.float32), root.astype(np.float32)

    def fill(self, motion, keys, seed=0, **kw):
        r, p = self.fill_batch(motion.rotations[None], motion.root_positions[None], np.asarray(keys))
        return replace(motion, rotations=r[0], root_positions=p[0])


@pytest.fixture(scope="module")
def walk(bandai_clip) -> Motion:
    m = read_bvh(bandai_clip).continuous().slice(100, 141)
    return Motion(SKEL, m.rotations, m.root_positions, 30.0)


def keys_equal(out: Motion, motion: Motion, keys) -> bool:
    return np.array_equal(out.rotations[keys], motion.rotations[keys]) and np.array_equal(
        out.root_positions[keys], motion.root_positions[keys]
    )


def test_probe_plan_leaves_interior_keys_out_in_local_windows():
    for keys in (PROTOCOL_KEYS, np.r_[np.arange(10), 15], np.arange(0, 3000, 10), np.array([0, 17, 40])):
        probes = trust.probe_plan(keys)
        assert 1 <= len(probes) <= trust.MAX_PROBES
        for p in probes:
            assert set(p.kept).isdisjoint(p.left_out) and set(p.kept) | set(p.left_out) <= set(keys.tolist())
            assert keys[0] not in p.left_out and keys[-1] not in p.left_out
            assert p.kept[0] < p.left_out[0] and p.left_out[-1] < p.kept[-1]
            assert p.lo == p.kept[0] and p.hi == p.kept[-1]
            assert p.hi - p.lo <= 3 * p.gap + 3  # local: no further than the hole's gap each side
            assert p.gap >= trust.MIN_GAP
    # The protocol's layout: holes in the context run, and the context's end joined to the gap.
    kinds = [p.kind for p in trust.probe_plan(PROTOCOL_KEYS)]
    assert kinds.count("run") == 3 and kinds.count("gap") == 1
    assert trust.probe_plan([0, 30]) == []


def test_cost_bound_probe_count_and_window_size(walk):
    long = Motion(SKEL, np.repeat(walk.rotations, 60, 0), np.repeat(walk.root_positions, 60, 0), 30.0)
    keys = np.arange(0, len(long), 8)
    model = StandIn("oracle")
    d = trust.decide(model, SplineInbetweener(), long, keys)
    assert model.calls == len(d.probes) <= trust.MAX_PROBES
    assert max(model.frames) <= 3 * 15 + 3  # local windows, not the 2,460-frame shot


def test_picks_the_model_that_fills_well_and_the_spline_over_garbage(walk):
    spline = SplineInbetweener()
    good = trust.decide(StandIn("oracle"), spline, walk, PROTOCOL_KEYS)
    assert good.choice == "model" and good.weight == 1.0
    assert good.model_error_cm < 1e-6 < good.spline_error_cm
    bad = trust.decide(StandIn("noise"), spline, walk, PROTOCOL_KEYS)
    assert bad.choice == "spline" and bad.weight == 0.0
    assert bad.model_error_cm > 10 * bad.spline_error_cm
    assert len(bad.probes) == len(trust.probe_plan(PROTOCOL_KEYS)) and bad.reason


def test_a_model_that_fills_nan_loses_its_probes_to_the_spline(walk):
    """Not a NaN weight, which blended neither fill (an internal error in the fill layer)."""
    inb = trust.TrustedInbetweener(StandIn("nan"), SplineInbetweener())
    out = inb.fill(walk, PROTOCOL_KEYS)
    d = inb.last_decision
    assert d.choice == "spline" and d.weight == 0.0 and np.isfinite(d.score)
    assert np.isfinite(out.rotations).all() and keys_equal(out, walk, PROTOCOL_KEYS)
    json.dumps(d.to_json(), allow_nan=False)  # the fill's JSON and layer record stay JSON


def test_trusted_fill_follows_the_decision_and_keeps_keys_bitwise(walk):
    spline = SplineInbetweener()
    for mode, choice in (("oracle", "model"), ("noise", "spline")):
        model = StandIn(mode)
        inb = trust.TrustedInbetweener(model, spline)
        out = inb.fill(walk, PROTOCOL_KEYS)
        assert inb.last_decision.choice == choice
        assert keys_equal(out, walk, PROTOCOL_KEYS)
        if choice == "spline":
            ref = spline.fill(walk, PROTOCOL_KEYS)
            assert np.array_equal(out.rotations, ref.rotations)
    assert inb.name == "stand-in" and inb.model_hash == "stand-in-hash" and inb.skeleton is SKEL


def test_overrides_run_no_probe(walk):
    spline = SplineInbetweener()
    model = StandIn("noise", seed=3)
    out = trust.TrustedInbetweener(model, spline, trust="model").fill(walk, PROTOCOL_KEYS)
    assert model.calls == 1  # the fill itself, no probes
    ref = StandIn("noise", seed=3).fill(walk, PROTOCOL_KEYS)
    assert np.array_equal(out.rotations, ref.rotations)
    model = StandIn("oracle")
    inb = trust.TrustedInbetweener(model, spline, trust="spline")
    out = inb.fill(walk, PROTOCOL_KEYS)
    assert model.calls == 0 and inb.last_decision.choice == "spline" and inb.last_decision.weight == 0.0
    assert np.array_equal(out.rotations, spline.fill(walk, PROTOCOL_KEYS).rotations)
    with pytest.raises(ValueError, match="unknown trust"):
        trust.TrustedInbetweener(model, spline, trust="maybe")


def test_blend_weight_bounds_and_exact_keys(walk):
    for score in np.linspace(-5, 5, 41):
        assert 0.0 <= trust.weight_of(score) <= 1.0
    assert trust.weight_of(-5) == 0.0 and trust.weight_of(5) == 1.0
    assert trust.weight_of(trust.THRESHOLD) == pytest.approx(0.5)
    # One probe cannot flip the model: a single probe's score is shrunk toward the model.
    assert trust.shrunk_score(np.array([trust.THRESHOLD - 0.3])) > trust.THRESHOLD - 0.3
    spline = SplineInbetweener()
    s = spline.fill(walk, PROTOCOL_KEYS)
    m = StandIn("noise").fill(walk, PROTOCOL_KEYS)
    ends = {}
    for w in (0.0, 0.3, 0.7, 1.0):
        d = trust.TrustDecision("blend", w, None, None)
        out = trust.apply(d, m, s)
        assert keys_equal(out, walk, PROTOCOL_KEYS)
        assert np.allclose(np.linalg.norm(out.rotations, axis=-1), 1.0, atol=1e-5)
        ends[w] = out
    assert ends[0.0] is s and ends[1.0] is m
    # The root moves linearly between the two fills.
    mid = trust.apply(trust.TrustDecision("blend", 0.3, None, None), m, s).root_positions
    assert np.allclose(mid, s.root_positions + 0.3 * (m.root_positions - s.root_positions), atol=1e-4)
    with pytest.raises(ValueError):
        trust.apply(trust.TrustDecision("spline", 0.0, None, None), m, None)


def test_decisions_are_json(walk):
    spline = SplineInbetweener()
    for model, mode in ((StandIn("oracle"), "auto"), (StandIn("noise"), "auto"), (StandIn("noise"), "model")):
        inb = trust.TrustedInbetweener(model, spline, trust=mode)
        inb.fill(walk, PROTOCOL_KEYS)
        text = json.dumps(inb.last_decision.to_json(), allow_nan=False)
        back = json.loads(text)
        assert back["choice"] in trust.CHOICES and 0.0 <= back["weight"] <= 1.0
        assert isinstance(back["reason"], str) and back["trust"] == mode
    two = trust.decide(StandIn("oracle"), spline, walk, [0, 40])  # two keys: nothing to probe
    assert two.choice == "model" and two.probes == [] and json.dumps(two.to_json(), allow_nan=False)


def test_partial_keys_reach_the_model_and_the_spline_holds_them(walk):
    keys = np.array([0, 10, 20, 30, 40])
    mask = np.ones((len(keys), len(SKEL) + 1), bool)
    mask[2, 5:] = False  # key 20 sets the first five joints only
    out = trust.spline_fill(SplineInbetweener(), walk, keys, mask)
    assert np.allclose(out.rotations[20, :5], walk.rotations[20, :5], atol=1e-6)
    assert keys_equal(out, walk, keys[[0, 1, 3, 4]])
    d = trust.TrustedInbetweener(StandIn("noise"), SplineInbetweener())
    d.fill(walk, keys, joint_keys=mask)
    # Probes use the four full keys only.
    assert all(20 not in p["left_out"] for p in d.last_decision.probes)


def test_shipped_model_on_an_eval_walk_keeps_keys_and_records_its_decision(walk):
    from pipeline.infer.api import load_inbetweener

    model = load_inbetweener("default")
    if getattr(model, "model_hash", "none") == "none":
        pytest.skip("no shipped model")
    inb = trust.trusted(model)
    assert isinstance(inb, trust.TrustedInbetweener) and trust.trusted(inb) is inb
    out = inb.fill(walk, PROTOCOL_KEYS)
    d = inb.last_decision
    assert keys_equal(out, walk, PROTOCOL_KEYS) and len(d.probes) == 4
    assert d.choice == "model", d.reason  # an eval walk: the network's own ground
    json.dumps(d.to_json(), allow_nan=False)
    assert trust.trusted(SplineInbetweener()).name == "spline"


def test_the_threshold_is_unbiased_at_the_probes_own_gaps_and_leans_to_the_model_on_long_ones():
    assert trust.threshold_for(1) == trust.threshold_for(trust.MIN_GAP) == 0.0
    assert trust.threshold_for(trust.LONG_GAP) == trust.threshold_for(90) == trust.THRESHOLD
    ramp = [trust.threshold_for(g) for g in range(trust.MIN_GAP, trust.LONG_GAP + 1)]
    assert all(a > b for a, b in zip(ramp, ramp[1:], strict=False))  # strictly falling between
    # Equal errors at the probes: a short gap gets one half, a long gap leans to the model.
    assert trust.weight_of(0.0, trust.threshold_for(5)) == pytest.approx(0.5)
    assert trust.weight_of(0.0, trust.threshold_for(30)) > 0.5


def test_each_gap_length_gets_its_own_weight_and_the_fill_blends_each_gap_at_it(walk):
    keys = np.r_[0:10, 13, 40]  # a run of keys (5-frame probe holes), a 3- and a 26-frame gap
    probes = trust.probe_plan(keys)
    assert min(p.gap for p in probes) == trust.MIN_GAP
    # The spline better at every probe (error ratio 0.74): the short gap, where the
    # probes are its own task, leans to the spline; the long gap still to the model.
    em = np.full(len(probes), 2.0)
    es = (em + trust.EPS_CM) * np.exp(-0.3) - trust.EPS_CM
    d = trust._decision(em, es, probes, keys)
    by_len = {g["length"]: g for g in d.gaps}
    assert set(by_len) == {3, 26} and by_len[3]["count"] == by_len[26]["count"] == 1
    assert by_len[3]["weight"] < 0.5 < by_len[26]["weight"] <= 1.0
    assert d.choice == "blend" and "per gap length" in d.reason
    assert d.weight == pytest.approx((3 * by_len[3]["weight"] + 26 * by_len[26]["weight"]) / 29, abs=1e-6)
    w = d.frame_weights(keys, len(walk.rotations))
    assert np.all(w[10:13] == by_len[3]["weight"]) and np.all(w[14:40] == by_len[26]["weight"])
    assert np.all(w[:10] == 1.0) and w[13] == w[40] == 1.0
    json.dumps(d.to_json(), allow_nan=False)
    # Applied with the keys, each gap is blended at its own weight.
    spline = SplineInbetweener()
    s, m = spline.fill(walk, keys), StandIn("noise").fill(walk, keys)
    out = trust.apply(d, m, s, keys)
    assert keys_equal(out, walk, keys)
    for f in (11, 30):
        r = out.root_positions[f]
        want = s.root_positions[f] + w[f] * (m.root_positions[f] - s.root_positions[f])
        assert np.allclose(r, want, atol=1e-3)
    # A gap where the model gets all of it is the model's fill there, bitwise.
    d.gaps[1]["weight"] = 1.0
    out = trust.apply(d, m, s, keys)
    assert np.array_equal(out.rotations[14:40], m.rotations[14:40])
    assert not np.array_equal(out.rotations[10:13], m.rotations[10:13])


def test_the_threshold_follows_the_probes_holes():
    # The ramp starts at the probes' shortest hole: scaled with it, and never below MIN_GAP.
    assert trust.threshold_for(29, hole=59) == trust.threshold_for(59, hole=59) == 0.0
    assert trust.threshold_for(3 * 59, hole=59) == trust.THRESHOLD
    assert trust.threshold_for(2 * 59, hole=59) == pytest.approx(trust.threshold_for(10))
    assert trust.threshold_for(12, hole=2) == trust.threshold_for(12)


def test_an_unseen_blocked_shot_trusts_its_leave_one_out_probes_own_score():
    """Keys every 30 frames: each probe leaves one key out (a 59-frame hole), so it asks the
    model for more than the shot's 29-frame gaps. Keys far from the training poses: the
    probes' score is taken as it is (threshold 0). Familiar keys (or a model without a pose
    bank): long gaps lean to the model as before. A shot with a run of keys (5-frame holes)
    leans to the model on long gaps however novel its keys."""
    keys = np.arange(0, 181, 30)
    probes = trust.probe_plan(keys)
    assert probes and all(p.gap == 59 for p in probes)
    em = np.full(len(probes), 2.0)
    es = (em + trust.EPS_CM) * np.exp(-0.3) - trust.EPS_CM  # the spline better by e^0.3
    unseen = trust._decision(em, es, probes, keys, novelty=novelty.NOVEL_CM + 1)
    assert [g["length"] for g in unseen.gaps] == [29] and unseen.gaps[0]["probe_hole"] == 59
    assert unseen.gaps[0]["threshold"] == 0.0 and unseen.choice == "spline" and unseen.weight == 0.0
    assert unseen.familiarity == 0.0 and unseen.novelty_cm == novelty.NOVEL_CM + 1
    assert "cm from the training poses" in unseen.reason
    json.dumps(unseen.to_json(), allow_nan=False)
    for seen in (trust._decision(em, es, probes, keys, novelty=1.0), trust._decision(em, es, probes, keys)):
        assert seen.gaps[0]["threshold"] == trust.THRESHOLD and seen.weight > 0.5
    half = trust._decision(em, es, probes, keys, novelty=(novelty.FAMILIAR_CM + novelty.NOVEL_CM) / 2)
    assert half.familiarity == pytest.approx(0.5) and half.gaps[0]["threshold"] == pytest.approx(
        trust.THRESHOLD / 2
    )
    dense = np.r_[0:10, 39, 69]
    dp = trust.probe_plan(dense)
    e2 = np.full(len(dp), 2.0)
    d2 = trust._decision(e2, (e2 + trust.EPS_CM) * np.exp(-0.3) - trust.EPS_CM, dp, dense, novelty=20.0)
    # (its probes' score at the long-gap threshold, and no credit for the model: one half)
    assert d2.gaps[0]["length"] == 29 and d2.gaps[0]["weight"] == pytest.approx(0.5)
    assert d2.gaps[0]["weight"] > unseen.weight
    # The model better at the probes: an unseen blocked shot takes the model.
    d3 = trust._decision(em, (em + trust.EPS_CM) * np.exp(0.3) - trust.EPS_CM, probes, keys, novelty=20.0)
    assert d3.choice == "model" and d3.weight == 1.0


def test_probes_on_keys_that_repeat_one_pose_while_the_character_travels_count_less(walk):
    """A walk keyed at its period: the spline lands on each left-out key (the same pose as its
    neighbours) though the character travelled metres across the hole. Such a probe counts in
    proportion to the spline's miss over ALIAS × the travel; a probe the character does not
    travel across, or one the spline misses by more, counts in full."""
    eps = trust.EPS_CM
    es = np.array([3.0, 1.5, 5.0, 0.0, eps, 1.5 * eps, 2 * eps])
    assert trust.alias_weights(es, np.array([10.0, 10.0, 0.0, 100.0, 100.0, 100.0, 100.0])) == (
        pytest.approx([1.0, 0.5, 1.0, 1.0, 1.0, 0.5, 2 * eps / 30.0])
    )  # (a pose held exactly: the animator's glide, which the spline gets right; it counts)
    holes = np.array([trust.CYCLE_FRAMES - 1, trust.CYCLE_FRAMES])
    assert trust.alias_weights(np.zeros(2) + 1.0, np.full(2, 100.0), holes) == pytest.approx([1.0, 1 / 30])
    keys = np.arange(0, 181, 30)
    probes = trust.probe_plan(keys)
    # One pose at every frame, the root walking 1.2 m/s along X (2.4 m across each hole).
    rot = np.broadcast_to(walk.rotations[0], (1, 181, *walk.rotations.shape[1:])).copy()
    root = np.zeros((1, 181, 3), np.float32)
    root[0, :, 0] = np.arange(181) * 4.0
    travel = trust.probe_travel_cm(root, probes, SKEL)
    assert travel == pytest.approx(np.full((1, len(probes)), 240.0))
    em = np.full(len(probes), 4.0)
    es = np.full(len(probes), 0.5)  # the spline lands on the repeated pose; the model 4 cm off
    plain = trust._decision(em, es, probes, keys, novelty=1.0)
    cyc = trust._decision(em, es, probes, keys, novelty=1.0, travel=travel[0])
    assert plain.weight < 0.5 < cyc.weight  # the familiar prior decides, not the aliased probes
    assert all(r["counted"] == pytest.approx(0.5 / (trust.ALIAS * 240.0), abs=1e-4) for r in cyc.probes)
    assert "repeating one pose" in cyc.reason and "repeating" not in plain.reason
    still = trust._decision(em, es, probes, keys, novelty=1.0, travel=np.zeros(len(probes)))
    assert still.weight == plain.weight and all(r["counted"] == 1.0 for r in still.probes)
    # Through decide_batch, the travel from the shot's own root: one pose held exactly while
    # the root walks is the animator's glide; the spline hits it, and its probes count in full.
    d = trust.decide_batch(StandIn("noise"), SplineInbetweener(SKEL), rot, root, keys)[0]
    assert all(r["counted"] == 1.0 and r["spline_cm"] < 0.01 for r in d.probes) and d.choice == "spline"


def test_novelty_tells_training_poses_from_offset_ones(walk):
    """The shipped pose bank: the walk's own keys (an eval clip of the training actors) are
    familiar; the same keys with 30-degree posture offsets are not; a model folder without a
    bank gives None and a broken bank file is refused naming it."""
    model = OnnxInbetweener("models/default")
    bank = model.pose_bank
    assert bank is not None and bank.shape == (4096, len(SKEL.names), 3)
    keys = np.arange(0, 41, 10)
    rot, root = walk.rotations[keys][None], walk.root_positions[keys][None]
    near = novelty.novelty_cm(rot, root, bank, SKEL)[0]
    offset = posture_offsets(rot, np.random.default_rng(0), 30.0, 1.0)
    far = novelty.novelty_cm(offset, root, bank, SKEL)[0]
    assert near < novelty.FAMILIAR_CM < novelty.NOVEL_CM < far
    assert novelty.familiarity(near) == 1.0 and novelty.familiarity(far) == 0.0
    # Moving and turning the character changes nothing: poses are root-relative, facing +X.
    turned = quat_mul(yaw_quat(np.full((1, len(keys)), 1.3)), rot[..., 0, :])
    moved = rot.copy()
    moved[..., 0, :] = turned
    assert novelty.novelty_cm(moved, root + 500.0, bank, SKEL)[0] == pytest.approx(near, abs=0.05)
    # Decisions through a model carry the keys' novelty.
    d = trust.decide(model, SplineInbetweener(), walk, np.arange(0, 41, 10))
    assert d.novelty_cm == pytest.approx(near, abs=1e-3) and d.familiarity == 1.0


def test_a_model_folder_without_or_with_a_broken_pose_bank(tmp_path):
    folder = tmp_path / "m"
    shutil.copytree("models/default", folder, ignore=shutil.ignore_patterns("torch", "bench"))
    meta = json.loads((folder / "model.json").read_text())
    del meta["pose_bank"]
    (folder / "model.json").write_text(json.dumps(meta))
    assert OnnxInbetweener(folder).pose_bank is None
    meta["pose_bank"] = "pose_bank.npz"
    (folder / "model.json").write_text(json.dumps(meta))
    (folder / "pose_bank.npz").unlink()
    with pytest.raises(ModelFolderError, match="pose_bank.npz: the pose bank model.json names is missing"):
        OnnxInbetweener(folder)
    (folder / "pose_bank.npz").write_bytes(b"not a bank")
    with pytest.raises(ModelFolderError, match="pose_bank.npz: not a pose bank"):
        OnnxInbetweener(folder)  # read and checked when the model loads


def test_a_shot_keyed_on_every_frame_has_nothing_to_blend():
    keys = np.arange(12)
    probes = trust.probe_plan(keys)  # holes in the run of keys
    assert probes
    d = trust._decision(np.full(len(probes), 2.0), np.full(len(probes), 1.0), probes, keys)
    assert d.gaps == [] and d.choice == "model" and "no frame between the keys" in d.reason
    assert np.array_equal(d.frame_weights(keys, 12), np.ones(12))


def test_gap_weights_at_fractional_frames():
    keys = np.r_[0:10, 13, 40]
    probes = trust.probe_plan(keys)
    em = np.full(len(probes), 2.0)
    d = trust._decision(em, (em + trust.EPS_CM) * np.exp(-0.3) - trust.EPS_CM, probes, keys)
    by_len = {g["length"]: g["weight"] for g in d.gaps}
    w = trust.gap_weights_at(d, keys, [0.0, 9.0, 9.5, 12.9, 13.0, 13.2, 39.99, 40.0, 45.0])
    assert list(w) == [1.0, 1.0, by_len[3], by_len[3], 1.0, by_len[26], by_len[26], 1.0, 1.0]
    # Whole frames: the same as frame_weights.
    assert np.array_equal(trust.gap_weights_at(d, keys, np.arange(41)), d.frame_weights(keys, 41))
    forced = trust.TrustDecision("spline", 0.0, None, None, [], "trust=spline", None, "spline")
    assert list(trust.gap_weights_at(forced, keys, [0.0, 5.5, 40.0])) == [1.0, 0.0, 1.0]


def test_novelty_of_a_shot_keyed_on_every_frame_is_bounded(walk, monkeypatch):
    """A thousand keys (four times MAX_KEYS): at most MAX_KEYS are compared, evenly spread, and
    the answer is the median of those (the same as all of them here, within a millimetre)."""
    import time

    bank = OnnxInbetweener("models/default").pose_bank
    reps = 25  # 1,025 keys: the reference over all of them is most of this test's time
    rot = np.concatenate([walk.rotations] * reps)[None]
    root = np.concatenate([walk.root_positions] * reps)[None]
    t = time.perf_counter()
    many = novelty.novelty_cm(rot, root, bank, SKEL)[0]
    assert time.perf_counter() - t < 30.0  # (about 1 s here; shared cores vary)
    monkeypatch.setattr(novelty, "MAX_KEYS", 10**6)
    assert many == pytest.approx(novelty.novelty_cm(rot, root, bank, SKEL)[0], abs=0.1)


def test_gaps_the_body_teleports_across_go_to_the_spline():
    """with_cuts: the pair's gap gets weight 0 whatever its length's weight; the other
    gaps keep theirs; weight and choice follow over the gap frames; pairs that are no gap of
    the keys (adjacent frames, not adjacent keys) change nothing."""
    keys = np.r_[0, 10, 20, 30]
    d = trust.TrustDecision("model", 1.0, 1.0, 2.0, [], "probes", 0.5, gaps=[{"length": 9, "weight": 1.0}])
    assert d.with_cuts([(0, 20), (5, 6)], keys) is d
    j = d.with_cuts([(10, 20)], keys)
    assert j.cuts == [[10, 20]] and j.choice == "blend" and j.weight == pytest.approx(2 / 3)
    assert "1 gap(s) the body teleports across: the spline" in j.reason
    w = j.frame_weights(keys, 31)
    assert list(w[1:10]) == [1.0] * 9 and list(w[11:20]) == [0.0] * 9 and list(w[21:30]) == [1.0] * 9
    assert list(trust.gap_weights_at(j, keys, [9.5, 10.0, 15.5, 20.0, 25.5])) == [1.0, 1.0, 0.0, 1.0, 1.0]
    every = j.with_cuts([(0, 10), (20, 30)], keys)
    assert every.choice == "spline" and every.weight == 0.0 and every.cuts == [[0, 10], [10, 20], [20, 30]]
    assert json.loads(json.dumps(every.to_json()))["cuts"] == [[0, 10], [10, 20], [20, 30]]


def test_a_trusted_fill_gives_a_teleport_gap_to_the_spline_and_keeps_keys(walk):
    keys = np.r_[0, 10, 20, 30, 40]
    model = trust.TrustedInbetweener(StandIn("noise"), trust="auto")
    out = model.fill(walk, keys, cuts=[(10, 20)])
    d = model.last_decision
    assert d.cuts == [[10, 20]] and keys_equal(out, walk, keys)
    spl = trust.spline_fill(model.spline, walk, keys, breaks=[(10, 20)])
    assert np.array_equal(out.rotations[11:20], spl.rotations[11:20])
    assert np.array_equal(out.root_positions[11:20], spl.root_positions[11:20])
    # The curve keeps the clamped slopes beside the cut: across it, the animator's spline.
    clamped = SplineInbetweener(walk.skeleton).fill(walk, keys)
    assert np.allclose(out.root_positions[11:20], clamped.root_positions[11:20], atol=1e-4)
    # --trust model is the model, unchecked: no gap is taken from it.
    forced = trust.TrustedInbetweener(StandIn("oracle"), trust="model")
    forced.fill(walk, keys, cuts=[(10, 20)])
    assert forced.last_decision.cuts == [] and forced.last_decision.weight == 1.0


def test_no_network_window_and_no_probe_spans_a_cut(walk):
    """fill_across_cuts fills each stretch of keys between cuts on its own (a lone key between
    two cuts is not filled); the frames inside a cut keep the input's values; across_cuts
    drops the probes whose window holds a cut."""
    keys = np.r_[0, 5, 10, 20, 25, 30, 40]
    model = StandIn("oracle")
    calls = []
    fill = model.fill
    model.fill = lambda motion, k, **kw: calls.append((len(motion), list(k))) or fill(motion, k, **kw)
    noisy = replace(walk, rotations=walk.rotations.copy())
    noisy.rotations[11:20] = [0.0, 0.0, 0.0, 1.0]
    out = trust.fill_across_cuts(model, noisy, keys, [(10, 20), (30, 40)])
    assert calls == [(11, [0, 5, 10]), (11, [0, 5, 10])]
    assert np.array_equal(out.rotations[11:20], noisy.rotations[11:20]) and keys_equal(out, noisy, keys)
    calls.clear()
    trust.fill_across_cuts(model, noisy, keys, [])
    assert calls == [(41, list(keys))]
    probes = trust.probe_plan(keys)
    kept = trust.across_cuts(probes, [(10, 20)])
    assert kept and len(kept) < len(probes)
    assert all(p.hi <= 10 or p.lo >= 20 for p in kept)
    d = trust.decide(StandIn("noise"), SplineInbetweener(SKEL), walk, keys, cuts=[(10, 20)])
    assert d.cuts == [[10, 20]] and all(p["frames"][1] <= 10 or p["frames"][0] >= 20 for p in d.probes)
    few = trust.decide(StandIn("noise"), SplineInbetweener(SKEL), walk, np.r_[0, 10, 20], cuts=[(0, 10)])
    assert few.probes == [] and few.reason.startswith("no probe possible away from the cuts")
    assert few.cuts == [[0, 10]] and few.choice == "blend" and few.weight == 0.5


def test_the_window_benches_decided_fill_is_the_trusted_fill_shot_for_shot(bandai_clip):
    """trusted_fill_windows (the trust and blocking benches) gives, for each of a batch of
    shots sharing their keys, bit for bit what trusted_fill gives that shot alone."""
    model = OnnxInbetweener("models/default")
    m = read_bvh(bandai_clip).continuous()
    keys = np.r_[0, 15, 30, 31, 32, 45, 60]
    shots = [Motion(SKEL, m.rotations[a : a + 61], m.root_positions[a : a + 61], 30.0) for a in (0, 80)]
    offset = posture_offsets(shots[1].rotations[None], np.random.default_rng(0), 24.0, 1.0)[0]
    shots[1] = replace(shots[1], rotations=offset)  # a pose 24° off the actors': a blend
    rots = np.stack([s.rotations for s in shots])
    roots = np.stack([s.root_positions for s in shots])
    got = trust.trusted_fill_windows(model, SplineInbetweener(SKEL), rots, roots, keys)
    assert {d.choice for d in got.decisions} == {"model", "blend"}
    for i, shot in enumerate(shots):
        one = trust.trusted_fill(trust.TrustedInbetweener(model, SplineInbetweener(SKEL)), shot, keys)
        assert np.array_equal(got.decided[0][i], one.rotations)
        assert np.array_equal(got.decided[1][i], one.root_positions)


class SplineStandIn(StandIn):
    """A network whose fill is the spline's: its probes tie the spline's (score 0)."""

    def fill_batch(self, rot, root, keys):
        self.calls += 1
        return SplineInbetweener(SKEL).fill_batch(rot, root, keys)


def test_a_network_without_familiar_credit_is_judged_by_its_probes_alone(walk):
    """A studio's fine-tune (model.json ``"familiar_credit": false``, as ``tween export``
    writes it for a run on ``--data``): tied with the spline at the probes, it gets one half on
    a blocked shot, not a familiar model's lean to it on gaps longer than the probes' holes."""
    keys = np.arange(0, 41, 10)
    rot, root = walk.rotations[None, :41], walk.root_positions[None, :41]
    given = trust.decide_batch(SplineStandIn("oracle"), SplineInbetweener(SKEL), rot, root, keys)[0]
    assert given.score == pytest.approx(0.0, abs=1e-9) and given.familiarity is None
    assert given.gaps[0]["threshold"] == pytest.approx(trust.threshold_for(9)) and given.weight > 0.9
    studio = SplineStandIn("oracle")
    studio.capabilities = replace(StandIn.capabilities, familiar_credit=False)
    net = trust.decide_batch(studio, SplineInbetweener(SKEL), rot, root, keys)[0]
    assert net.score == given.score and net.familiarity == 0.0
    assert net.gaps[0]["threshold"] == 0.0 and net.weight == pytest.approx(0.5)
    assert "no familiar credit" in net.reason and "no familiar credit" not in given.reason
    assert net.to_json()["familiar_credit"] is False and given.to_json()["familiar_credit"] is True
    assert "no familiar credit" in trust_line(net.to_json()) and "credit" not in trust_line(given.to_json())


def test_probes_of_a_densely_keyed_long_shot_cost_in_line_with_its_keys():
    """Each probe scanned every key: 8,000 keys (a mocap shot keyed on twos, 16,000 frames)
    took 26 s and 20,000 about 8 minutes; bisection makes it well under a second."""
    import time

    from pipeline.infer.trust import probe_plan

    keys = np.arange(0, 40_000, 2)
    t0 = time.perf_counter()
    probes = probe_plan(keys)
    assert time.perf_counter() - t0 < 10.0  # 20,000 keys; about 0.5 s here, minutes before
    assert probes and all(p.kept[0] <= p.left_out[0] and p.left_out[-1] <= p.kept[-1] for p in probes)
