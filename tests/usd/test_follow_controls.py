"""Kept root controls that follow a character joint (pipeline.usd.follow): an IK target on
an ankle, a prop in a hand. The fill fills the character between the keys; such a control,
kept as authored before, stayed on the unfilled path while the filled joint moved away (up to
4.3 cm on the Blender export in tests/fixtures/blender), so a live IK constraint in the
animator's rig dragged the filled leg back onto it. It now moves with the filled joint,
keeping its transform relative to the joint interpolated between the keys; its keys stay bit
for bit, and a control on no joint stays as authored at every time."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from usd_fixtures import add_root_joints, digest, layer_samples, tween

ATTRS = ("rotations", "translations", "scales")
BLENDER = Path(__file__).resolve().parents[1] / "fixtures" / "blender" / "ik_roots.usda"
WALK = Path(__file__).resolve().parents[2] / "examples" / "sh010_walk.usda"


def _skel_transforms(path: Path, root: str, skel: str, times) -> tuple[list[str], np.ndarray]:
    """(joint names, (T, J, 4, 4) row-vector skeleton-space transforms): UsdSkel's reading of
    the composed stage at ``path`` (a viewer's, IK controls included)."""
    from pxr import Usd, UsdSkel

    stage = Usd.Stage.Open(str(path))
    cache = UsdSkel.Cache()
    cache.Populate(UsdSkel.Root(stage.GetPrimAtPath(root)), Usd.PrimDefaultPredicate)
    query = cache.GetSkelQuery(UsdSkel.Skeleton(stage.GetPrimAtPath(skel)))
    names = [str(t).rsplit("/", 1)[-1] for t in query.GetJointOrder()]
    return names, np.array([np.array(query.ComputeJointSkelTransforms(Usd.TimeCode(t))) for t in times])


def _in_frame(mats: np.ndarray, j: int, c: int) -> np.ndarray:
    """(T, 3): joint ``c``'s position in joint ``j``'s frame (row-vector matrices)."""
    return np.einsum("ti,tij->tj", np.c_[mats[:, c, 3, :3], np.ones(len(mats))], np.linalg.inv(mats[:, j]))[
        :, :3
    ]


def _one_warning(err: str) -> str:
    lines = [ln for ln in err.splitlines() if "root joints" in ln]
    assert len(lines) == 1, err
    assert "error" not in err and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize("model", ["interp", "default"])
def test_a_blender_ik_target_follows_the_filled_ankle(tmp_path, monkeypatch, capsys, model):
    from pxr import Usd

    skel, anim = "/root/Armature/Armature", "/root/Armature/Armature/ArmatureAction"
    keys = [float(k) for k in range(1, 62, 10)]
    shot = tmp_path / "ik_roots.usda"
    shutil.copyfile(BLENDER, shot)
    before = digest(shot)
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--keys", "1-61x10", "--model", model)
    assert rc == 0, err
    assert _one_warning(err).endswith(
        "are not filled: between the keys 'foot_ik_L' follows the filled 'Foot_L'; 'knee_pole_L' stays as authored"
    ), err
    assert digest(shot) == before  # the animator's file is never written

    frames = [float(t) for t in range(1, 62)]
    names, src = _skel_transforms(shot, "/root/Armature", skel, frames)
    _, out = _skel_transforms(tmp_path / "ik_roots.review.v001.usda", "/root/Armature", skel, frames)
    foot, target = names.index("Foot_L"), names.index("foot_ik_L")
    at_keys = [frames.index(k) for k in keys]
    # Blender's IK leaves the ankle on the target, or short of it by up to 1.9 cm at the keys
    # where the target is out of the leg's reach (metersPerUnit 1).
    off = np.linalg.norm(src[:, target, 3, :3] - src[:, foot, 3, :3], axis=1)
    assert 0.015 < off[at_keys].max() < 0.02
    # Blender's target against the filled ankle (what the fill kept before): up to 4.3 cm.
    kept = np.linalg.norm(src[:, target, 3, :3] - out[:, foot, 3, :3], axis=1)
    assert kept.max() > 0.04, kept.max()
    # The filled target against the filled ankle: never further than at the keys, and its
    # place on the ankle is the keys' interpolated (lerp between the keys around).
    got = np.linalg.norm(out[:, target, 3, :3] - out[:, foot, 3, :3], axis=1)
    assert got.max() <= off[at_keys].max() + 1e-5, got.max()
    rel = _in_frame(out, foot, target)
    want = np.stack([np.interp(frames, keys, _in_frame(src, foot, target)[at_keys, i]) for i in range(3)], 1)
    assert np.abs(rel - want).max() < 1e-5

    # Keys bit for bit, every joint; the pole at every time.
    stage = Usd.Stage.Open(str(shot))  # held: its prims expire with it
    a = stage.GetPrimAtPath(anim)
    joints, filled = layer_samples(tmp_path / "ik_roots.tween.v001.usda", f"{anim}_tween", ATTRS)
    pole = joints.index("knee_pole_L")
    for name in ATTRS:
        for t, v in filled[name].items():
            authored = np.array(a.GetAttribute(name).Get(t))
            assert np.array_equal(v[pole], authored[pole]), (name, t)
            if t in keys:
                assert np.array_equal(v, authored), (name, t)


SKEL, ANIM = "/World/Walker/Skel", "/World/Walker/Skel/Anim"
CONTROLS = ["Prop", "Free", "Still"]  # on the right hand; moving on its own; never moving


def _rel():
    """The prop's fixed transform in the hand's frame (row-vector): 8 cm off it, turned 30°."""
    from pxr import Gf

    return Gf.Matrix4d().SetTransform(Gf.Rotation(Gf.Vec3d(1, 2, 3), 30.0), Gf.Vec3d(0, -8, 3))


def _with_controls(shot: Path) -> None:
    """Adds three root controls to the walk (pxr API): a prop keyed in the right hand at every
    key (its position between keys USD's interpolation, not the hand's), a control moving on
    its own, and one that never moves."""
    from pxr import Gf, Usd, UsdSkel, Vt

    stage = Usd.Stage.Open(str(shot))
    cache = UsdSkel.Cache()
    cache.Populate(UsdSkel.Root(stage.GetPrimAtPath("/World/Walker")), Usd.PrimDefaultPredicate)
    query = cache.GetSkelQuery(UsdSkel.Skeleton(stage.GetPrimAtPath(SKEL)))
    hand = [str(t) for t in query.GetJointOrder()].index(
        "Hips/Spine/Chest/Shoulder_R/UpperArm_R/LowerArm_R/Hand_R"
    )
    anim = stage.GetPrimAtPath(ANIM)
    keys = anim.GetAttribute("rotations").GetTimeSamples()
    held = {
        k: UsdSkel.DecomposeTransform(_rel() * query.ComputeJointSkelTransforms(Usd.TimeCode(k))[hand])
        for k in keys
    }
    add_root_joints(stage.GetPrimAtPath(SKEL), anim, CONTROLS)
    rot, tr = anim.GetAttribute("rotations"), anim.GetAttribute("translations")
    for k in keys:
        t, r, _ = held[k]
        free = Gf.Quatf(Gf.Rotation(Gf.Vec3d(0, 1, 0), (k - 1000) * 3).GetQuat())
        rot.Set(Vt.QuatfArray(list(rot.Get(k)) + [Gf.Quatf(r), free, Gf.Quatf(1)]), k)
        moves = Gf.Vec3f(40 - (k - 1000) * 2, 60, (k - 1000) % 17)
        tr.Set(Vt.Vec3fArray(list(tr.Get(k)) + [Gf.Vec3f(t), moves, Gf.Vec3f(5, 5, 5)]), k)
    sc = anim.GetAttribute("scales")
    sc.Set(Vt.Vec3hArray(list(sc.Get()) + [Gf.Vec3h(1, 1, 1)] * len(CONTROLS)))
    stage.Save()


@pytest.mark.parametrize("model", ["interp", "default"])
def test_a_prop_follows_the_filled_hand_and_a_free_control_stays_as_authored(
    tmp_path, monkeypatch, capsys, model
):
    from pxr import Usd

    shot = tmp_path / "sh010.usda"
    shutil.copyfile(WALK, shot)
    _with_controls(shot)
    before = digest(shot)
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--model", model)
    assert rc == 0, err
    assert _one_warning(err).endswith(
        "are not filled: between the keys 'Prop' follows the filled 'Hand_R'; 'Free', 'Still' stay as authored"
    ), err
    assert digest(shot) == before

    stage = Usd.Stage.Open(str(shot))
    src = stage.GetPrimAtPath(ANIM)
    keys = src.GetAttribute("rotations").GetTimeSamples()
    joints, filled = layer_samples(tmp_path / "sh010.tween.v001.usda", f"{ANIM}_tween", ATTRS)
    times = sorted(filled["rotations"])
    assert len(times) > 3 * len(keys)
    still = [joints.index("Free"), joints.index("Still")]
    for name in ATTRS:
        for t, v in filled[name].items():
            authored = np.array(src.GetAttribute(name).Get(t))
            assert np.array_equal(v[still], authored[still]), (name, t)  # on no joint: as authored
            if t in keys:
                assert np.array_equal(v, authored), (name, t)
    # The prop sits on the filled hand at every frame as it does at the keys (float32 values
    # a metre from the origin: to a hundredth of a millimetre, metersPerUnit 0.01).
    names, out = _skel_transforms(tmp_path / "sh010.review.v001.usda", "/World/Walker", SKEL, times)
    p, h = names.index("Prop"), names.index("Hand_R")
    rel = np.array(_rel())
    held = np.einsum("ij,tjk->tik", rel, out[:, h])
    assert np.abs(out[:, p, 3, :3] - held[:, 3, :3]).max() < 1e-3
    rot = np.einsum("tij,tkj->tik", out[:, p, :3, :3], held[:, :3, :3])  # the rotation between
    # Its angle from |R - I| (2√2·sin(θ/2)), exact near 0 where arccos of the trace is not.
    angle = np.degrees(2 * np.arcsin(np.linalg.norm(rot - np.eye(3), axis=(1, 2)) / (2 * np.sqrt(2))))
    assert angle.max() < 0.01, angle.max()
    # USD's interpolation of the prop's keys (what was kept before) leaves the filled hand.
    _, plain = _skel_transforms(shot, "/World/Walker", SKEL, times)
    drift = np.linalg.norm(plain[:, p, 3, :3] - held[:, 3, :3], axis=1)
    assert drift.max() > 1.0, drift.max()


def test_the_keys_around_a_range_judge_the_controls_and_one_key_follows_nothing():
    from pxr import Usd

    from pipeline.usd import follow

    stage = Usd.Stage.Open(str(BLENDER))
    skel = "/root/Armature/Armature"
    src = stage.GetPrimAtPath(f"{skel}/ArmatureAction")
    authored = [str(t) for t in src.GetAttribute("joints").Get()]
    rig = follow.rig_of(stage, skel, authored)
    keys = np.arange(1.0, 62.0, 10.0)
    times = np.arange(1.0, 62.0)
    # A --range between keys (16-26) is filled from the keys around it: those judge the controls.
    around = follow.fill_keys(keys, times, (times > 15) & (times < 27), inside=times[15:26])
    assert around.tolist() == [11.0, 21.0, 31.0]
    assert follow.keys_around(keys, 21.0, 41.0).tolist() == [21.0, 31.0, 41.0]  # a range on keys
    said = follow.detect(rig, around, *follow.values_at(src, authored, rig, around))
    assert rig.joints[said[0].joint].endswith("/Foot_L") and authored[said[0].slot] == "foot_ik_L"
    # One key is no evidence of following: nothing follows.
    one = keys[2:3]
    said = follow.detect(rig, one, *follow.values_at(src, authored, rig, one))
    assert [(authored[f.slot], f.joint) for f in said] == [("foot_ik_L", -1), ("knee_pole_L", -1)]


def test_a_range_between_keys_moves_the_target_there_and_keeps_it_elsewhere(tmp_path, monkeypatch, capsys):
    """``--range 16-26`` fills only those frames, from the keys around them (11, 21, 31): the
    target follows the filled ankle there, judged by those keys, and is Blender's elsewhere."""
    skel = "/root/Armature/Armature"
    shot = tmp_path / "ik_roots.usda"
    shutil.copyfile(BLENDER, shot)
    args = ("fill-local", shot, "--keys", "1-61x10", "--range", "16-26", "--model", "interp")
    rc, err = tween(monkeypatch, capsys, *args)
    assert rc == 0, err
    assert "between the keys 'foot_ik_L' follows the filled 'Foot_L'" in _one_warning(err), err
    frames = [float(t) for t in range(1, 62)]
    names, src = _skel_transforms(shot, "/root/Armature", skel, frames)
    _, out = _skel_transforms(tmp_path / "ik_roots.review.v001.usda", "/root/Armature", skel, frames)
    foot, target = names.index("Foot_L"), names.index("foot_ik_L")
    inside = [frames.index(t) for t in frames if 16 <= t <= 26 and t != 21]
    outside = [frames.index(t) for t in frames if not 16 <= t <= 26]
    assert np.array_equal(out[outside, target], src[outside, target])  # Blender's, bit for bit
    moved = np.linalg.norm(out[inside, target, 3, :3] - src[inside, target, 3, :3], axis=1)
    assert moved.max() > 1e-3, moved  # the filled leg moved it
    keys = [11.0, 21.0, 31.0]
    at = [frames.index(k) for k in keys]
    rel = _in_frame(out, foot, target)[inside]
    want = np.stack(
        [np.interp([frames[i] for i in inside], keys, _in_frame(src, foot, target)[at, i]) for i in range(3)],
        1,
    )
    assert np.abs(rel - want).max() < 1e-5


def _blender_rig():
    from pxr import Usd

    from pipeline.usd import follow

    stage = Usd.Stage.Open(str(BLENDER))
    src = stage.GetPrimAtPath("/root/Armature/Armature/ArmatureAction")
    authored = [str(t) for t in src.GetAttribute("joints").Get()]
    return stage, src, authored, follow.rig_of(stage, "/root/Armature/Armature", authored)


def test_a_mirrored_or_vanishing_joint_is_followed_without_a_crash():
    """A joint of negative scale (a Maya rig's mirrored side) or one scaled to nothing between
    keys has no rotation scipy's from_matrix takes: the follow still finds and moves the
    target, on the nearest proper rotation."""
    from pipeline.usd import follow

    _, src, authored, rig = _blender_rig()
    keys, times = np.arange(1.0, 62.0, 10.0), np.arange(1.0, 62.0)
    foot = next(i for i, t in enumerate(authored) if t.endswith("/Foot_L"))
    thigh = next(i for i, t in enumerate(authored) if t.endswith("/UpperLeg_L"))
    values = follow.values_at(src, authored, rig, keys)
    values[2][:, foot] = (-1, 1, 1)  # mirrored at every key
    said = follow.detect(rig, keys, *values)
    assert rig.joints[said[0].joint].endswith("/Foot_L")
    r, t, s = (v.astype(np.float32) for v in follow.values_at(src, authored, rig, times))
    s[:, foot] = (-1, 1, 1)
    s[4, thigh] = 0  # frame 5: the leg above it scaled to nothing
    follow.apply(rig, said, times, r, t, s, follow.off_keys(keys, times))
    assert np.isfinite(r).all() and np.isfinite(t).all()
    assert np.allclose(np.linalg.norm(r[:, said[0].slot], axis=1), 1, atol=1e-5)


def test_moving_the_controls_of_a_long_fill_takes_bounded_memory():
    """30,000 moved frames: the skeleton's transforms are computed a block of frames at a time
    (every joint's 4x4 at every frame at once peaked at 312 MB on this 23-joint rig)."""
    import tracemalloc

    from pipeline.usd import follow

    _, src, authored, rig = _blender_rig()
    keys = np.arange(1.0, 62.0, 10.0)
    said = follow.detect(rig, keys, *follow.values_at(src, authored, rig, keys))
    r, t, s = (v.astype(np.float32) for v in follow.values_at(src, authored, rig, keys[:1]))
    n = 30_000
    r, t, s = (np.repeat(v, n, 0) for v in (r, t, s))
    tracemalloc.start()
    try:
        follow.apply(rig, said, np.linspace(1.5, 60.5, n), r, t, s, np.ones(n, bool))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 120e6, peak / 1e6


def test_a_mirrored_rest_pose_under_an_unauthored_attribute_reads_as_the_writer_keeps_it(tmp_path):
    """Where the animation authors no scales, a joint shows its rest transform: a mirrored one
    (scale -1 in its rest) decomposed by UsdSkel, as the writer keeps it (read.rest_values),
    not by scipy's from_matrix, which refused it."""
    from pxr import Gf, Usd, Vt

    from pipeline.usd import follow

    shot = tmp_path / "ik_roots.usda"  # a copy: the fixture's layer is never edited in memory
    shutil.copyfile(BLENDER, shot)
    stage = Usd.Stage.Open(str(shot))
    src = stage.GetPrimAtPath("/root/Armature/Armature/ArmatureAction")
    authored = [str(t) for t in src.GetAttribute("joints").Get()]
    skel = stage.GetPrimAtPath("/root/Armature/Armature")
    rest_attr = skel.GetAttribute("restTransforms")
    rest = list(rest_attr.Get())
    foot = [str(t) for t in skel.GetAttribute("joints").Get()].index("Hips/UpperLeg_L/LowerLeg_L/Foot_L")
    rest[foot] = Gf.Matrix4d().SetScale(Gf.Vec3d(-1, 1, 1)) * rest[foot]
    rest_attr.Set(Vt.Matrix4dArray(rest))
    src.GetAttribute("scales").Clear()
    rig = follow.rig_of(stage, "/root/Armature/Armature", authored)
    keys = np.arange(1.0, 62.0, 10.0)
    values = follow.values_at(src, authored, rig, keys)
    slot = authored.index("Hips/UpperLeg_L/LowerLeg_L/Foot_L")
    assert np.allclose(values[2][:, slot], (-1, 1, 1)) or np.allclose(np.prod(values[2][:, slot], 1), -1)
    said = follow.detect(rig, keys, *values)
    assert rig.joints[said[0].joint].endswith("/Foot_L")
