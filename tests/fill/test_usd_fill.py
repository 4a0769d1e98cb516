"""Filling shots end to end: layers, keys bitwise, every frame, rates, ranges, takes, hashes."""

import numpy as np
import pytest
from usd_fixtures import ANIM, BANDAI_CLIP, FILLED, bandai_shot, cmu_shot, samples, tree_hashes

from pipeline.errors import ShotError, TweenError
from pipeline.fill.api import FillOptions, fill_shot, fill_take, validate_shot, write_layers
from pipeline.infer.interp import interpolate_keys
from pipeline.motion.bvh import read_bvh


def _open(path):
    from pxr import Usd

    return Usd.Stage.Open(str(path))


def rig_curve(shot, keys=None):
    """The own-rig plan of ``shot`` and the trusted curve as the fill runs it on the rig: its
    feet planted on the rig's legs as the human mapping finds them (solve.rig_feet)."""
    from pipeline.fill import solve
    from pipeline.fill.plan import make_plan
    from pipeline.infer.trust import trusted_curve

    own = make_plan(str(shot), keys, None, None, 30.0, own_rig=True)
    human = make_plan(str(shot), keys, None, None, 30.0)
    feet = solve.rig_feet(human.chars[0].retarget, own.chars[0].retarget.skeleton)
    assert feet is not None
    curve = trusted_curve()
    plain_fill = curve.fill
    curve.fill = lambda motion, at, **kw: plain_fill(motion, at, feet=feet, **kw)
    return own, curve


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    d = tmp_path_factory.mktemp("walk")
    return bandai_shot(d / "walk.usda", frames=61, keys_every=10)


def test_fill_writes_layers_keys_bitwise_every_frame(walk, tmp_path):
    shots = walk.parent
    before = tree_hashes(shots)
    res = fill_shot(str(walk), FillOptions(model="interp", out_dir=str(tmp_path)))
    assert tree_hashes(shots) == before  # the animator's files are untouched
    assert res["layer"].endswith("walk.tween.v001.usda") and res["version"] == 1 and res["takes"] == 1
    review = _open(res["review"])
    assert review.GetTimeCodesPerSecond() == 30
    # The review stage resolves the filled animation on every frame.
    from pxr import UsdSkel

    skel = UsdSkel.Skeleton(review.GetPrimAtPath("/World/Character/Skel"))
    assert UsdSkel.BindingAPI(skel).GetAnimationSourceRel().GetTargets() == [FILLED]
    filled = samples(review, FILLED)
    assert sorted(filled) == [float(t) for t in range(1001, 1062)]
    orig = samples(review, ANIM)
    assert sorted(orig) == [float(t) for t in range(1001, 1062, 10)]
    for t, v in orig.items():
        assert filled[t].dtype == np.float32 and np.array_equal(filled[t].view(np.uint32), v.view(np.uint32))
    # In-betweens: the model skeleton is the rig, so the fill is the interpolation baseline itself.
    src = read_bvh(BANDAI_CLIP).slice(0, 61)
    want = interpolate_keys(src, np.arange(0, 61, 10)).rotations
    got = np.stack([filled[1001.0 + f] for f in range(61)])
    assert np.abs(np.abs((got * want).sum(-1)) - 1).max() < 1e-5
    tr = samples(review, FILLED, "translations")
    assert len(tr) == 61 and len(samples(review, FILLED, "scales")) == 61
    a = review.GetPrimAtPath(FILLED)
    assert a.HasAPI("TweenAPI") and a.GetAttribute("tween:model").Get() == "interpolation"
    assert list(a.GetAttribute("tween:keyTimes").Get()) == [float(t) for t in range(1001, 1062, 10)]
    # UsdSkel poses the skeleton from the fill (all three components authored).
    from pxr import Usd

    cache = UsdSkel.Cache()
    cache.Populate(UsdSkel.Root(review.GetPrimAtPath("/World/Character")), Usd.PrimDefaultPredicate)
    q = cache.GetSkelQuery(skel)
    assert q.GetAnimQuery().GetPrim().GetPath() == FILLED
    assert len(q.GetAnimQuery().ComputeJointLocalTransformComponents(1005)[1]) == 21
    # usd-core's own validators find nothing wrong with the composed review stage.
    from pxr import UsdValidation

    ctx = UsdValidation.ValidationContext(UsdValidation.ValidationRegistry().GetOrLoadAllValidators())
    assert [e.GetMessage() for e in ctx.Validate(review)] == []


def test_versions_never_overwrite_and_usdc_and_job_id(walk, tmp_path):
    o = FillOptions(model="interp", out_dir=str(tmp_path))
    r1 = fill_shot(str(walk), o, job_id="job-a")
    first = open(r1["layer"], "rb").read()
    r2 = fill_shot(str(walk), FillOptions(model="interp", out_dir=str(tmp_path), fmt="usdc"), job_id="job-b")
    assert r2["version"] == 2 and r2["layer"].endswith("walk.tween.v002.usdc")
    assert open(r1["layer"], "rb").read() == first
    r3 = fill_shot(str(walk), o, job_id="job-a")  # same job: the existing layer, no new version
    assert r3["layer"] == r1["layer"] and r3["version"] == 1
    assert len(list(tmp_path.glob("walk.tween.v*"))) == 2
    assert not list(tmp_path.glob(".*"))  # no temp files left


def test_fill_take_idempotent_and_takes_variant_set(walk, tmp_path):
    o = FillOptions(model="interp", out_dir=str(tmp_path / "out"), takes=2, seed=7)
    validate_shot(str(walk), o)
    work = tmp_path / "work"
    files = [fill_take(str(walk), o, t, str(work)) for t in range(2)]
    assert fill_take(str(walk), o, 0, str(work)) == files[0]
    mtime = (work / files[0].split("/")[-1]).stat().st_mtime_ns
    assert fill_take(str(walk), o, 0, str(work)) == files[0]
    assert (work / files[0].split("/")[-1]).stat().st_mtime_ns == mtime
    res = write_layers(str(walk), o, files, job_id="j1")
    stage = _open(res["review"])
    world = stage.GetPrimAtPath("/World")
    vs = world.GetVariantSets().GetVariantSet("tweenTake")
    assert vs.GetVariantNames() == ["take0", "take1"] and vs.GetVariantSelection() == "take0"
    anim = stage.GetPrimAtPath(FILLED)
    assert (
        anim.GetAttribute("tween:seed").Get() == 7
        and len(anim.GetAttribute("rotations").GetTimeSamples()) == 61
    )
    vs.SetVariantSelection("take1")
    assert anim.GetAttribute("tween:seed").Get() == 8 and anim.GetAttribute("tween:take").Get() == 1
    assert len(anim.GetAttribute("rotations").GetTimeSamples()) == 61
    assert world.HasAPI("TweenAPI") and world.GetAttribute("tween:reviewStatus").Get() == "pending"
    assert world.GetAttribute("tween:approvedTake").Get() == -1


def test_a_job_written_again_returns_what_the_first_write_returned(walk, tmp_path):
    """A farm task delivered again after it wrote (a worker lost after the write): the same
    layer, no new version, and the same decisions, identical takes and licences in its result
    (the client prints them and the render stage skips identical takes by them)."""
    o = FillOptions(out_dir=str(tmp_path / "out"), takes=2, seed=7)
    validate_shot(str(walk), o)
    files = [fill_take(str(walk), o, t, str(tmp_path / "work")) for t in range(2)]
    first = write_layers(str(walk), o, files, job_id="j1")
    again = write_layers(str(walk), o, files, job_id="j1")
    assert again["layer"] == first["layer"] and again["version"] == first["version"] == 1
    assert len(list((tmp_path / "out").glob("walk.tween.v*"))) == 1
    for k in ("trust", "jumps", "same_as", "licence", "missing_assets"):
        assert again[k] == first[k], k
    assert any(first["trust"].values())  # the default model was trusted or not, by its probes


def test_range_fills_part_and_keeps_the_rest(walk, tmp_path):
    res = fill_shot(str(walk), FillOptions(model="interp", out_dir=str(tmp_path), range="1015-1035"))
    stage = _open(res["review"])
    filled = samples(stage, FILLED)
    orig = stage.GetPrimAtPath(ANIM).GetAttribute("rotations")
    assert sorted(filled) == [float(t) for t in range(1001, 1062)]
    for t in (1001, 1005, 1014, 1036, 1050, 1061):  # outside the range: what the shot has
        assert np.array_equal(filled[float(t)], np.array(orig.Get(t)))
    assert not np.allclose(filled[1025.0], filled[1015.0])


def test_24fps_shot_keeps_keys_at_their_time_codes(tmp_path):
    shot = bandai_shot(tmp_path / "sh24.usda", frames=91, keys_every=9, fps=24)
    res = fill_shot(str(shot), FillOptions(model="interp", out_dir=str(tmp_path / "o")))
    stage = _open(res["review"])
    assert stage.GetTimeCodesPerSecond() == 24
    orig, filled = samples(stage, ANIM), samples(stage, FILLED)
    end = stage.GetEndTimeCode()
    assert sorted(filled) == [float(t) for t in range(1001, int(end) + 1)]
    for t, v in orig.items():
        assert np.array_equal(filled[t], v)
    # Between keys the motion is smooth: neighbouring frames are close.
    seq = np.stack([filled[t] for t in sorted(filled)])
    assert np.abs(np.abs((seq[1:] * seq[:-1]).sum(-1)) - 1).max() < 0.05


def test_non_integer_time_codes_and_keys_override(tmp_path):
    shot = bandai_shot(tmp_path / "frac.usda", frames=41, keys_every=4, start=1000.25)
    o = FillOptions(model="interp", out_dir=str(tmp_path / "o"), keys="1000.25,1020.25,1040.25")
    s = validate_shot(str(shot), o)
    assert s["keys"][ANIM] == [1000.25, 1020.25, 1040.25]
    res = fill_shot(str(shot), o)
    stage = _open(res["review"])
    filled, orig = samples(stage, FILLED), samples(stage, ANIM)
    for t in (1000.25, 1020.25, 1040.25):
        assert np.array_equal(filled[t], orig[t])
    assert 1001.0 in filled and 1040.0 in filled  # every integer frame of the range, keys exact
    # 1004.25 was an authored sample but not a key: it is filled, not copied.
    assert not np.array_equal(filled.get(1004.25, filled[1004.0]), orig[1004.25])


def test_cc_rig_z_up_60fps_maps_and_keeps_unmapped_joints(tmp_path):
    shot = cmu_shot(tmp_path / "cc.usda", frames=121, keys_every=12)
    before = tree_hashes(tmp_path)
    # The network's own fill (the trusted fill picks the rig's spline for this take).
    res = fill_shot(str(shot), FillOptions(model="default", trust="model", out_dir=str(tmp_path / "o")))
    after = tree_hashes(tmp_path)
    assert {k: after[k] for k in before} == before
    stage = _open(res["review"])
    assert stage.GetTimeCodesPerSecond() == 60
    anim = stage.GetPrimAtPath(ANIM)
    joints = [str(j).rsplit("/", 1)[-1] for j in anim.GetAttribute("joints").Get()]
    assert len(joints) == 100
    filled, orig_attr = samples(stage, FILLED), anim.GetAttribute("rotations")
    assert sorted(filled) == [float(t) for t in range(1001, 1122)]
    for t in orig_attr.GetTimeSamples():
        assert np.array_equal(filled[t], np.array(orig_attr.Get(t)))
    # Unmapped joints (fingers, twist, face) keep their own values, interpolated by USD.
    for name in ("CC_Base_L_Index2", "CC_Base_R_ForearmTwist01", "CC_Base_JawRoot", "CC_Base_Pelvis"):
        j = joints.index(name)
        for t in (1005.0, 1018.0, 1100.0):
            np.testing.assert_array_equal(filled[t][j], np.array(orig_attr.Get(t))[j])
    # Mapped joints are really retargeted: the thigh between keys follows a smooth path
    # near USD's own per-joint SLERP, but not on it.
    th = joints.index("CC_Base_L_Thigh")
    seq = np.stack([filled[float(t)][th] for t in range(1001, 1122)])
    assert np.abs(np.abs((seq[1:] * seq[:-1]).sum(-1)) - 1).max() < 0.02
    usd = np.array(orig_attr.Get(1006.0))[th]
    assert 1e-6 < abs(abs(float(usd @ filled[1006.0][th])) - 1) < 0.05


def test_the_trusted_fill_blends_with_the_splines_on_the_rig_itself(tmp_path, monkeypatch):
    """Where the decision is the spline, the default fill is the trusted fill's curve filled
    on the rig itself (the spline through the keys with adaptive tangents, as the animator's
    ``--model spline`` fills it with clamped ones) bit for bit, every one of its 100 joints;
    a blend lies between the network's fill and that curve, keys exact. (The network against
    the spline: the library shipped beside it holds this very take.)"""
    from pipeline.fill import api, solve
    from pipeline.fill.plan import make_plan
    from pipeline.infer.api import load_inbetweener
    from pipeline.infer.trust import TrustDecision, TrustedInbetweener

    monkeypatch.setattr(api, "SHIPPED_LIBRARY", False)
    shot = cmu_shot(tmp_path / "cc.usda", frames=121, keys_every=12)
    runs = {
        name: fill_shot(str(shot), FillOptions(model=model, trust=trust, out_dir=str(tmp_path / name)))
        for name, model, trust in (
            ("auto", "default", "auto"),
            ("net", "default", "model"),
            ("forced", "default", "spline"),
            ("animator", "spline", "auto"),
        )
    }
    got = {name: samples(_open(r["review"]), FILLED) for name, r in runs.items()}
    own, on_rig = rig_curve(shot)
    curve = solve.fill_character(own, own.chars[0], on_rig, seed=0)
    got["rig"] = {
        float(t): r for t, r in zip(curve["times"], curve["rot"], strict=True) if float(t) in got["auto"]
    }
    d = runs["auto"]["trust"][ANIM]
    assert d["choice"] == "spline" and d["familiarity"] == 0.0  # a CMU take: unseen, spline better
    assert d["curve"] == "adaptive"  # recorded: which tangents the spline took
    assert d["plant"] is True  # ... and that it holds the feet the keys plant
    for name in ("auto", "forced"):
        assert got[name].keys() == got["rig"].keys()
        assert all(np.array_equal(got[name][t], got["rig"][t]) for t in got["rig"])
    assert any(not np.array_equal(got["net"][t], got["rig"][t]) for t in got["rig"])
    # Keys every 12 frames at 30 fps are dense: the curve is not the clamped one.
    assert any(not np.allclose(got["animator"][t], got["rig"][t], atol=1e-4) for t in got["rig"])
    # A blend: half way between the two fills, joint by joint (SLERP at w = 0.5).

    class Halfway(TrustedInbetweener):
        def decide(self, motion, keys, cuts=()):
            self.last_decision = TrustDecision("blend", 0.5, None, None, [], "half", None)
            return self.last_decision

    plan = make_plan(str(shot), None, None, None, 30.0)
    cp = plan.chars[0]
    half = solve.fill_character(plan, cp, Halfway(load_inbetweener("default")), seed=0)
    net = solve.fill_character(plan, cp, load_inbetweener("default"), seed=0, trust="model")
    rig = got["rig"]
    i = int(np.flatnonzero(half["times"] == 1006.0)[0])
    a, b = net["rot"][i].astype(np.float64), np.array(rig[1006.0], np.float64)
    b = np.where((a * b).sum(-1, keepdims=True) < 0, -b, b)
    mid = (a + b) / np.linalg.norm(a + b, axis=-1, keepdims=True)
    h = half["rot"][i].astype(np.float64)
    assert np.abs(np.abs((h * mid).sum(-1)) - 1).max() < 1e-5
    for t in (1001.0, 1013.0, 1121.0):  # keys: the authored values
        j = int(np.flatnonzero(half["times"] == t)[0])
        assert np.array_equal(half["rot"][j], np.array(rig[t]))


@pytest.mark.parametrize("trust", ["auto", "model"])
def test_a_60fps_shot_keyed_on_consecutive_frames_fills(tmp_path, capfd, trust):
    """60 fps, keys every 12 frames and the last one frame after the one before (a hold, as
    an animator keys it): two keys on one model frame. The network sees one of them; every
    key keeps its authored values and the frames between keys are filled."""
    shot = cmu_shot(tmp_path / "cc.usda", frames=122, keys_every=12)
    res = fill_shot(str(shot), FillOptions(model="default", trust=trust, out_dir=str(tmp_path / "o")))
    err = capfd.readouterr().err
    assert "keys 1121 and 1122 fall on one model frame (1/30 s): the network sees one key" in err
    stage = _open(res["review"])
    filled, orig = samples(stage, FILLED), stage.GetPrimAtPath(ANIM).GetAttribute("rotations")
    assert sorted(filled) == [float(t) for t in range(1001, 1123)]
    for t in orig.GetTimeSamples():
        assert np.array_equal(filled[t], np.array(orig.Get(t)))
    seq = np.stack([filled[float(t)] for t in range(1001, 1123)])
    assert np.isfinite(seq).all()
    steps = np.abs(np.abs((seq[1:] * seq[:-1]).sum(-1)) - 1).max(-1)
    assert steps.max() < 0.05  # no jump between consecutive frames, the two keys included


def test_each_gap_blends_on_the_rig_at_its_own_weight(tmp_path):
    """Gap weights 0, 1 and 1/2: the first gap is the trusted curve on the rig bit for bit,
    the second the network's fill on the rig, the third between them."""
    from pipeline.fill import solve
    from pipeline.fill.plan import make_plan
    from pipeline.infer.api import load_inbetweener
    from pipeline.infer.trust import TrustDecision, TrustedInbetweener

    shot = str(cmu_shot(tmp_path / "cc.usda", frames=121, keys_every=12))
    keys = "1001,1013,1049,1121"  # 60 fps: gaps of 5, 17 and 35 model frames
    weights = {5: 0.0, 17: 1.0, 35: 0.5}

    class Fixed(TrustedInbetweener):
        def decide(self, motion, keys, cuts=()):
            gaps = [{"length": n, "count": 1, "weight": w} for n, w in weights.items()]
            self.last_decision = TrustDecision("blend", 0.5, None, None, [], "fixed", None, gaps=gaps)
            return self.last_decision

    plan = make_plan(shot, keys, None, None, 30.0)
    mix = solve.fill_character(plan, plan.chars[0], Fixed(load_inbetweener("default")), seed=0)
    net = solve.fill_character(plan, plan.chars[0], load_inbetweener("default"), seed=0, trust="model")
    own, on_rig = rig_curve(shot, keys)
    spl = solve.fill_character(own, own.chars[0], on_rig, seed=0)
    t = mix["times"]
    assert np.array_equal(t, net["times"]) and np.array_equal(t, spl["times"])
    first, second, third = ((t > a) & (t < b) for a, b in ((1001, 1013), (1013, 1049), (1049, 1121)))
    assert np.array_equal(mix["rot"][first], spl["rot"][first])
    assert np.array_equal(mix["rot"][second], net["rot"][second])
    a, b, h = (x["rot"][third].astype(np.float64) for x in (net, spl, mix))
    b = np.where((a * b).sum(-1, keepdims=True) < 0, -b, b)
    mid = (a + b) / np.linalg.norm(a + b, axis=-1, keepdims=True)
    assert np.abs(np.abs((h * mid).sum(-1)) - 1).max() < 1e-5
    assert not np.array_equal(h, a) and not np.array_equal(h, b)


def test_keys_that_all_fall_on_one_model_frame_are_one_clear_line(tmp_path):
    shot = cmu_shot(tmp_path / "cc.usda", frames=122, keys_every=12)
    with pytest.raises(ShotError, match=r"keys 1001-1002 all fall on one model frame \(1/30 s\)"):
        fill_shot(str(shot), FillOptions(model="default", keys="1001,1002", out_dir=str(tmp_path / "o")))
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_interp_fills_any_rig_in_its_own_space(tmp_path):
    """--model interp needs no mapping: an unmappable rig (joints renamed to nonsense) is
    interpolated joint by joint, as USD itself interpolates between the keys."""
    from pxr import Usd, Vt

    shot = cmu_shot(tmp_path / "cc.usda", frames=61, keys_every=12)
    stage = Usd.Stage.Open(str(shot))
    skel = stage.GetPrimAtPath(ANIM).GetParent()
    tokens = [str(t) for t in skel.GetAttribute("joints").Get()]
    renamed = ["/".join(f"j{abs(hash(p)) % 10**6}" for p in t.split("/")) for t in tokens]
    skel.GetAttribute("joints").Set(Vt.TokenArray(renamed))
    stage.GetPrimAtPath(ANIM).GetAttribute("joints").Set(Vt.TokenArray(renamed))
    stage.GetRootLayer().Save()
    with pytest.raises(ShotError, match="map"):
        validate_shot(str(shot), FillOptions(model="default"))
    res = fill_shot(str(shot), FillOptions(model="interp", out_dir=str(tmp_path / "o")))
    out = _open(res["review"])
    filled = samples(out, FILLED)
    src = Usd.Stage.Open(str(shot))
    orig = src.GetPrimAtPath(ANIM)
    for t in (1001.0, 1013.0):  # keys: bitwise
        assert np.array_equal(filled[t], np.array(orig.GetAttribute("rotations").Get(t)))
    for t in (1005.0, 1018.0, 1050.0):  # between keys: USD's SLERP of the same keys
        usd = np.array(orig.GetAttribute("rotations").Get(t))
        assert np.abs(np.abs((filled[t] * usd).sum(-1)) - 1).max() < 1e-5


def test_animators_sublayers_untouched_and_named_review_layer(walk, tmp_path):
    from pxr import Sdf

    shots = tmp_path / "published"
    shots.mkdir()
    anim_layer = bandai_shot(shots / "anim.usda", frames=31, keys_every=10)
    root = Sdf.Layer.CreateNew(str(shots / "sh010.usda"))
    src = Sdf.Layer.FindOrOpen(str(anim_layer))
    from pxr import UsdUtils

    UsdUtils.CopyLayerMetadata(src, root, True, True)
    root.subLayerPaths = ["anim.usda"]
    root.Save()
    review = Sdf.Layer.CreateNew(str(tmp_path / "dailies.usda"))
    review.subLayerPaths = [str(shots / "sh010.usda")]
    UsdUtils.CopyLayerMetadata(root, review, True, True)
    review.Save()
    before = tree_hashes(shots)
    res = fill_shot(
        str(shots / "sh010.usda"),
        FillOptions(
            model="interp", out_dir=str(tmp_path / "out"), review_layer=str(tmp_path / "dailies.usda")
        ),
    )
    assert tree_hashes(shots) == before
    assert res["review"] == str(tmp_path / "dailies.usda")
    lay = Sdf.Layer.OpenAsAnonymous(str(tmp_path / "dailies.usda"))
    assert list(lay.subLayerPaths)[0].endswith("sh010.tween.v001.usda") and len(lay.subLayerPaths) == 2
    stage = _open(tmp_path / "dailies.usda")
    assert len(samples(stage, FILLED)) == 31


def _dailies_layer(path, shot):
    from pxr import Sdf, UsdUtils

    review = Sdf.Layer.CreateNew(str(path))
    review.subLayerPaths = [str(shot)]
    UsdUtils.CopyLayerMetadata(Sdf.Layer.FindOrOpen(str(shot)), review, True, True)
    review.Save()
    return path


def test_a_read_only_review_layer_is_refused_untouched(tmp_path):
    """A --review-layer the user made read-only is refused before anything runs (it was
    rewritten, and came back writable)."""
    import os

    shot = bandai_shot(tmp_path / "sh010.usda", frames=21, keys_every=10)
    dailies = _dailies_layer(tmp_path / "dailies.usda", shot)
    os.chmod(dailies, 0o444)
    before = dailies.read_bytes()
    opts = FillOptions(model="interp", out_dir=str(tmp_path / "out"), review_layer=str(dailies))
    with pytest.raises(TweenError, match="dailies.usda: read-only"):
        fill_shot(str(shot), opts)
    assert dailies.read_bytes() == before and (dailies.stat().st_mode & 0o777) == 0o444
    assert not (tmp_path / "out").exists()


def test_a_linked_review_layer_is_written_through_its_link_keeping_its_mode(tmp_path):
    """A --review-layer that is a symbolic link stays one: the file it names gets the fill,
    with the mode it had (it was replaced by a plain file, world-readable, and the file the
    link named never got the fill)."""
    import os

    from pxr import Sdf

    shot = bandai_shot(tmp_path / "sh010.usda", frames=21, keys_every=10)
    real = _dailies_layer(tmp_path / "real.usda", shot)
    os.chmod(real, 0o640)
    link = tmp_path / "dailies.usda"
    link.symlink_to(real.name)
    fill_shot(str(shot), FillOptions(model="interp", out_dir=str(tmp_path), review_layer=str(link)))
    assert link.is_symlink() and os.readlink(link) == "real.usda"
    assert (real.stat().st_mode & 0o777) == 0o640
    layer = Sdf.Layer.OpenAsAnonymous(str(real))
    subs = list(layer.subLayerPaths)
    assert subs[0].endswith("sh010.tween.v001.usda") and len(subs) == 2


def test_an_output_folder_reached_through_a_link_composes_from_both_paths(tmp_path):
    """--out-dir through a symbolic link to a folder elsewhere: the review layer named the shot
    relative to the link's target (``../../../shots/sh010.usda``), and opened at the path
    printed (through the link) it composed without the shot: no animation, exit 0."""
    from pxr import Usd, UsdSkel

    shot = bandai_shot(tmp_path / "shots" / "sh010.usda", frames=21, keys_every=10)
    real = tmp_path / "real" / "deep" / "out"
    real.mkdir(parents=True)
    (tmp_path / "shots" / "out").symlink_to(real)
    res = fill_shot(str(shot), FillOptions(model="interp", out_dir=str(tmp_path / "shots" / "out")))
    assert res["review"] == str(tmp_path / "shots" / "out" / "sh010.review.v001.usda")
    for review in (res["review"], str(real / "sh010.review.v001.usda")):
        stage = Usd.Stage.Open(review)
        anims = [UsdSkel.Animation(p) for p in stage.Traverse() if p.IsA(UsdSkel.Animation)]
        assert len(stage.GetLayerStack(False)) == 3, review
        assert max(len(a.GetRotationsAttr().GetTimeSamples()) for a in anims) == 21, review


def test_a_shot_name_too_long_for_its_layers_is_refused_and_the_longest_fills(tmp_path):
    """A 250-byte shot name failed on a take's temp file ("File name too long", naming the
    temp); the refusal says how long a name may be here, and a name that long fills."""
    from pipeline.usd import files

    room = 255 - len(files.owner_tag().encode()) - 60
    long = bandai_shot(tmp_path / ("s" * (room + 1) + ".usda"), frames=21, keys_every=10)
    with pytest.raises(TweenError, match=f"is {room + 1} bytes.* at most {room} here"):
        fill_shot(str(long), FillOptions(model="interp"))
    assert sorted(p.name for p in tmp_path.iterdir()) == [long.name]
    ok = bandai_shot(tmp_path / ("s" * room + ".usda"), frames=21, keys_every=10)
    assert fill_shot(str(ok), FillOptions(model="interp", takes=2))["version"] == 1


def test_a_shot_named_with_a_leading_dot_is_refused(tmp_path):
    """``..sh.usda`` had no part before its first dot: its layers were hidden
    (``.tween.v001.usda``), one series for every such shot in the folder."""
    shot = bandai_shot(tmp_path / "..sh.usda", frames=21, keys_every=10)
    with pytest.raises(TweenError, match="its name starts with a dot"):
        fill_shot(str(shot), FillOptions(model="interp"))
    assert [p.name for p in tmp_path.iterdir()] == ["..sh.usda"]


def test_blend_shape_weights_are_kept(tmp_path):
    from pxr import Sdf, Usd, UsdSkel, Vt

    shot = bandai_shot(tmp_path / "bs.usda", frames=21, keys_every=10)
    stage = Usd.Stage.Open(str(shot))
    anim = UsdSkel.Animation(stage.GetPrimAtPath(ANIM))
    anim.CreateBlendShapesAttr(Vt.TokenArray(["smile", "blink"]))
    w = anim.CreateBlendShapeWeightsAttr()
    for t, v in ((1001, [0.0, 1.0]), (1007, [0.5, 0.0]), (1021, [1.0, 0.25])):
        w.Set(Vt.FloatArray(v), t)
    stage.GetRootLayer().Save()
    del stage
    res = fill_shot(str(shot), FillOptions(model="interp", out_dir=str(tmp_path / "o")))
    st = _open(res["review"])
    f = st.GetPrimAtPath(FILLED)
    assert list(f.GetAttribute("blendShapes").Get()) == ["smile", "blink"]
    bw = f.GetAttribute("blendShapeWeights")
    assert bw.GetTimeSamples() == [1001.0, 1007.0, 1021.0]
    assert list(bw.Get(1007)) == [0.5, 0.0]
    assert Sdf  # noqa: B018


def test_write_speed_10000_frames_100_joints(tmp_path):
    """The documented number: authoring 10,000 frames × 100 joints into a fill layer."""
    import time

    from pxr import Sdf, Usd

    from pipeline.usd.write import author_fill_layer

    T, J = 10000, 100
    rng = np.random.default_rng(0)
    q = rng.normal(size=(T, J, 4)).astype(np.float32)
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    data = {"times": np.arange(T, dtype=np.float64) + 1001, "rot": q,
            "trans": rng.normal(size=(T, J, 3)).astype(np.float32), "scale": np.ones((T, J, 3), np.float16)}  # fmt: skip
    stage = Usd.Stage.CreateInMemory()
    stage.DefinePrim("/World/C/Skel/Anim", "SkelAnimation")
    chars = [{"anim": "/World/C/Skel/Anim", "skel": "/World/C/Skel", "joints": [f"j{i}" for i in range(J)],
              "keys": [1001.0, 11000.0]}]  # fmt: skip
    layer = Sdf.Layer.CreateNew(str(tmp_path / "big.tween.v001.usdc"))
    t0 = time.perf_counter()
    author_fill_layer(layer, stage, [{"chars": chars, "data": [data], "take": 0, "seed": 0}],
                      {"model": "m", "model_hash": "h", "job_id": "", "created_at": "now"})  # fmt: skip
    t1 = time.perf_counter()
    layer.Save()
    t2 = time.perf_counter()
    print(f"\nauthor {t1 - t0:.2f} s, save usdc {t2 - t1:.2f} s")
    assert t2 - t0 < 6.0  # ~1 s on an idle 2-core machine; generous for a loaded CI box
    back = Sdf.Layer.OpenAsAnonymous(str(tmp_path / "big.tween.v001.usdc"))
    path = Sdf.Path("/World/C/Skel/Anim_tween.rotations")
    assert back.GetNumTimeSamplesForPath(path) == T
    assert np.array_equal(np.array(back.QueryTimeSample(path, 5000.0 + 1001)), q[5000])


def test_a_review_layer_that_already_names_the_version_gets_it_strongest_once(tmp_path):
    """A --review-layer still listing a version since removed (its name about to be written
    again) was an internal error, USD's "Duplicate item not allowed for field 'subLayers'"."""
    from pxr import Sdf

    shot = bandai_shot(tmp_path / "sh010.usda", frames=21, keys_every=10)
    (tmp_path / "out").mkdir()
    dailies = tmp_path / "out" / "dailies.usda"
    layer = Sdf.Layer.CreateNew(str(dailies))
    layer.subLayerPaths = ["../sh010.usda", "./sh010.tween.v001.usda"]  # weakest, another spelling
    layer.Save()
    fill_shot(
        str(shot), FillOptions(model="interp", out_dir=str(tmp_path / "out"), review_layer=str(dailies))
    )
    written = Sdf.Layer.OpenAsAnonymous(str(dailies))
    assert list(written.subLayerPaths) == ["sh010.tween.v001.usda", "../sh010.usda"]


def test_fills_into_one_review_layer_take_turns_and_none_is_lost(tmp_path):
    """Two fills of different output folders into one --review-layer each read the layer,
    added their fill and wrote it back: one fill was gone from it (both said "review: it").
    Now each holds the layer's lock from reading it to writing it: a fill waits while another
    writer holds it, then adds its fill to what that one wrote."""
    import subprocess
    import sys
    import time

    from pxr import Sdf

    from pipeline.atomic import locked

    shot = bandai_shot(tmp_path / "sh010.usda", frames=21, keys_every=10)
    dailies = _dailies_layer(tmp_path / "dailies.usda", shot)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "pipeline.cli", "fill-local", str(shot), "--model", "interp", "--out-dir", str(out),
           "--review-layer", str(dailies)]  # fmt: skip
    with locked(tmp_path / ".dailies.usda.lock"):  # another fill is writing the layer
        p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        t0 = time.monotonic()
        while not (out / "sh010.tween.v001.usda").exists():
            assert p.poll() is None and time.monotonic() - t0 < 120, p.communicate()[1][-2000:]
            time.sleep(0.05)
        time.sleep(1.0)
        assert p.poll() is None, "the fill wrote the review layer without its lock"
        other = Sdf.Layer.OpenAsAnonymous(str(dailies))  # what the other writer adds meanwhile
        subs = ["other/sh010.tween.v001.usda", *list(other.subLayerPaths)]
        other.subLayerPaths = subs
        other.Export(str(dailies))
    _, err = p.communicate(timeout=120)
    assert p.returncode == 0, err[-2000:]
    after = Sdf.Layer.OpenAsAnonymous(str(dailies))
    subs = list(after.subLayerPaths)
    assert subs == ["out/sh010.tween.v001.usda", "other/sh010.tween.v001.usda", str(shot)], subs
    assert not (tmp_path / ".dailies.usda.lock").exists()
