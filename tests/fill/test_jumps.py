"""Keys the body teleports between: said on stderr, in the fill's JSON and on the layer."""

import numpy as np
from usd_fixtures import ANIM, FILLED, bandai_shot, tree_hashes

from pipeline.fill.api import FillOptions, fill_shot
from pipeline.fill.jumps import JUMP_MPS, body_centre, jump_line, key_jumps


def _moved(shot, time: float, dx_cm: float) -> None:
    """Moves the root joint of the shot's animation by ``dx_cm`` along X at ``time``."""
    from pxr import Gf, Usd

    stage = Usd.Stage.Open(str(shot))
    attr = stage.GetPrimAtPath(ANIM).GetAttribute("translations")
    tr = attr.Get(time)
    tr[0] = tr[0] + Gf.Vec3f(dx_cm, 0, 0)
    attr.Set(tr, time)
    stage.GetRootLayer().Save()


def test_a_key_six_metres_off_is_flagged_and_the_fill_still_goes_through_it(tmp_path, capfd):
    shot = bandai_shot(tmp_path / "shots" / "walk.usda", frames=61, keys_every=10)
    _moved(shot, 1031.0, 600.0)  # 6 m in 1/3 s: 18 m/s there and back
    before = tree_hashes(shot.parent)
    res = fill_shot(str(shot), FillOptions(model="interp", out_dir=str(tmp_path / "o")))
    assert tree_hashes(shot.parent) == before
    err = capfd.readouterr().err
    assert f"tween: warning: {shot} {ANIM}: keys 1021 and 1031 and 1 more pair(s): the body moves" in err
    assert "faster than anyone runs): a capture glitch or a cut? filled as keyed" in err
    jumps = res["jumps"][ANIM]
    assert [(j["from"], j["to"]) for j in jumps] == [(1021.0, 1031.0), (1031.0, 1041.0)]
    assert all(j["mps"] > JUMP_MPS and 5.5 < j["metres"] < 6.5 for j in jumps)
    from pxr import Usd

    stage = Usd.Stage.Open(res["review"])
    pairs = stage.GetPrimAtPath(FILLED).GetAttribute("tween:keyJumps").Get()
    assert [tuple(p) for p in pairs] == [(1021.0, 1031.0), (1031.0, 1041.0)]
    # Filled as keyed: the moved key keeps its value.
    tr = stage.GetPrimAtPath(FILLED).GetAttribute("translations")
    src = stage.GetPrimAtPath(ANIM).GetAttribute("translations")
    assert np.array_equal(np.array(tr.Get(1031.0)), np.array(src.Get(1031.0)))


def test_a_warning_is_said_once_whatever_the_takes(tmp_path, capfd):
    """Each take plans the shot again; its notes were said again for every take."""
    shot = bandai_shot(tmp_path / "walk.usda", frames=61, keys_every=10)
    _moved(shot, 1031.0, 600.0)
    fill_shot(str(shot), FillOptions(model="interp", takes=3, out_dir=str(tmp_path / "o")))
    assert capfd.readouterr().err.count("the body moves") == 1


def test_a_plain_walk_has_no_jumps_and_no_attribute(tmp_path, capfd):
    shot = bandai_shot(tmp_path / "walk.usda", frames=61, keys_every=10)
    res = fill_shot(str(shot), FillOptions(model="interp", out_dir=str(tmp_path / "o")))
    assert res["jumps"] == {ANIM: []}
    assert "the body moves" not in capfd.readouterr().err
    from pxr import Usd

    stage = Usd.Stage.Open(res["review"])
    assert not stage.GetPrimAtPath(FILLED).GetAttribute("tween:keyJumps").HasAuthoredValue()


def test_the_body_centre_moves_with_the_whole_body_not_with_one_joint():
    """Three joints in a chain: the root moving 1 m moves the centre 1 m; the last joint's
    translation moving 1 m moves it a third of that. Over 1/30 s the first is a jump, and a
    single joint flipping as far is not."""
    parents = np.array([-1, 0, 1])
    rot = np.tile([0.0, 0.0, 0.0, 1.0], (2, 3, 1))
    trans = np.zeros((2, 3, 3))
    trans[:, 1:, 1] = 0.5
    whole = trans.copy()
    whole[1, 0, 0] = 1.0
    one = trans.copy()
    one[1, 2, 0] = 1.0
    c_whole, c_one = body_centre(parents, rot, whole), body_centre(parents, rot, one)
    assert np.allclose(c_whole[1] - c_whole[0], [1.0, 0, 0])
    assert np.allclose(c_one[1] - c_one[0], [1 / 3, 0, 0])
    times = np.array([1001.0, 1002.0])
    assert len(key_jumps(times, c_whole, 30.0)) == 1  # 30 m/s
    assert key_jumps(times, c_one * 0.4, 30.0) == []  # 4 m/s
    # A joint turned moves its children: a 90° turn of the middle joint swings the tip.
    turned = rot.copy()
    turned[1, 1] = [0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)]
    c = body_centre(parents, turned, trans)
    assert np.allclose(c[1] - c[0], [-0.5 / 3, -0.5 / 3, 0])


def test_the_default_fill_gives_the_gaps_across_a_teleport_to_the_rigs_spline(tmp_path):
    from pipeline.fill import solve
    from pipeline.fill.plan import make_plan
    from pipeline.infer.api import load_inbetweener

    shot = bandai_shot(tmp_path / "walk.usda", frames=61, keys_every=10)
    _moved(shot, 1031.0, 600.0)
    plan = make_plan(str(shot), None, None, None, 30.0)
    got = solve.fill_character(plan, plan.chars[0], load_inbetweener("default"), seed=0)
    assert got["trust"]["cuts"] == [[20, 30], [30, 40]]
    own = make_plan(str(shot), None, None, None, 30.0, own_rig=True)
    spl = solve.fill_character(own, own.chars[0], load_inbetweener("spline"), seed=0)
    net = solve.fill_character(plan, plan.chars[0], load_inbetweener("default"), seed=0, trust="model")
    t = got["times"]
    assert np.array_equal(t, spl["times"])
    across = (t > 1021) & (t < 1041) & (t != 1031)
    # The keys beside a cut keep the clamped slope, so across it the trusted fill's curve is
    # the animator's spline (to rounding: one Hermite evaluation against scipy's PCHIP).
    assert np.allclose(got["rot"][across], spl["rot"][across], atol=1e-6)
    assert np.allclose(got["trans"][across], spl["trans"][across], atol=1e-4)
    assert not np.allclose(net["rot"][across], spl["rot"][across], atol=1e-3)
    # --trust spline is the same curve, cuts and all: the cuts are the keys', not the decision's.
    forced = solve.fill_character(plan, plan.chars[0], load_inbetweener("default"), seed=0, trust="spline")
    assert np.array_equal(forced["rot"][across], got["rot"][across])
    assert np.array_equal(forced["trans"][across], got["trans"][across])
    assert net["trust"]["cuts"] == []  # --trust model: the network, unchecked


def _path(paces, dt):
    """Body centres (K, 3) walking along X at each gap's pace (m/s), keys ``dt`` s apart."""
    steps = np.zeros((len(paces), 3))
    steps[:, 0] = np.asarray(paces) * dt
    return np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])


def test_a_spike_in_pace_is_a_jump_and_a_sprint_start_or_capture_jitter_is_not():
    dt, tcps = 1 / 3, 30.0
    times = 1001 + np.arange(7) * 10.0  # keys every 10 frames at 30 fps
    walk_glitch = _path([1.2, 1.2, 7.0, 1.2, 1.2, 1.2], dt)  # one gap 2.3 m: 7 m/s, no sprint
    (j,) = key_jumps(times, walk_glitch, tcps, up=1)
    assert (j["from"], j["to"], j["why"]) == (1021.0, 1031.0, "spike") and j["mps"] == 7.0
    assert jump_line([j]).startswith("keys 1021 and 1031: the body moves 2.33 m in 0.333 s (7 m/s, a change")
    first = _path([7.0, 1.2, 1.2, 1.2, 1.2, 1.2], dt)  # a glitch on the first key: one neighbour
    assert [(x["from"], x["why"]) for x in key_jumps(times, first, tcps, up=1)] == [(1001.0, "spike")]
    sprint = _path([0.0, 2.0, 4.0, 6.0, 8.0, 9.0], dt)  # 6 m/s² at most
    assert key_jumps(times, sprint, tcps, up=1) == []
    stop = _path([6.0, 3.0, 0.5, 0.0, 0.0, 0.0], dt)  # a hard stop, 9 m/s²
    assert key_jumps(times, stop, tcps, up=1) == []
    # A jump's landing changes the vertical pace, not the horizontal one: not a spike.
    land = _path([1.0] * 6, dt)
    land[3:, 1] = -2.0  # 2 m down in one gap (6 m/s), then level
    assert key_jumps(times, land, tcps, up=1) == []
    assert [x["why"] for x in key_jumps(times, land, tcps, up=None)] == ["spike"]
    # Capture on every frame at 60 fps: 1 cm of jitter is no jump.
    rng = np.random.default_rng(0)
    dense = _path([1.5] * 600, 1 / 60) + rng.normal(scale=0.01, size=(601, 3))
    assert key_jumps(1001 + np.arange(601.0), dense, 60.0, up=1) == []


def test_a_60fps_shots_jump_is_cut_on_the_models_30fps_frames(tmp_path):
    """Keys every 10 frames at 60 fps: the pair 1061-1071 is model frames 30-35 (30 fps)."""
    from usd_fixtures import cmu_shot

    from pipeline.fill import solve
    from pipeline.fill.plan import make_plan
    from pipeline.infer.api import load_inbetweener

    shot = cmu_shot(tmp_path / "cc.usda", frames=121, keys_every=10)
    from pxr import Gf, Usd

    stage = Usd.Stage.Open(str(shot))
    attr = stage.GetPrimAtPath(ANIM).GetAttribute("translations")
    tr = attr.Get(1071.0)
    tr[0] = tr[0] + Gf.Vec3f(250.0, 0, 0)  # 2.5 m sideways, one key (the rig is in cm)
    attr.Set(tr, 1071.0)
    stage.GetRootLayer().Save()
    plan = make_plan(str(shot), None, None, None, 30.0)
    assert [(j["from"], j["to"]) for j in plan.chars[0].jumps] == [(1061.0, 1071.0), (1071.0, 1081.0)]
    got = solve.fill_character(plan, plan.chars[0], load_inbetweener("default"), seed=0)
    assert got["trust"]["cuts"] == [[30, 35], [35, 40]]


def test_the_body_centre_of_many_keys_is_computed_in_blocks(monkeypatch):
    """Blocks of keys give the same centres as one pass (memory follows the block)."""
    from pipeline.fill import jumps
    from pipeline.motion.rotations import quat_normalize

    rng = np.random.default_rng(1)
    parents = np.array([-1, 0, 1, 1, 3])
    rot = quat_normalize(rng.normal(size=(37, 5, 4)))
    trans = rng.normal(size=(37, 5, 3))
    whole = body_centre(parents, rot, trans)
    monkeypatch.setattr(jumps, "BLOCK", 8)
    assert np.allclose(body_centre(parents, rot, trans), whole, atol=1e-12)
