"""Feet the keys plant stay planted (pipeline.infer.plant) in the trusted fill's curve."""

from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.data.skeletons import LEGS, bandai_skeleton
from pipeline.infer.plant import PLANT_HEIGHT_CM, PLANT_TRAVEL_CM, feet_of, model_feet, plant_feet, planted
from pipeline.infer.post import two_bone_ik
from pipeline.infer.spline import SplineInbetweener, spline_motion
from pipeline.infer.trust import CURVE, trusted_curve
from pipeline.motion.bvh import read_bvh
from pipeline.motion.fk import fk
from pipeline.motion.skeleton import Skeleton

SKEL = bandai_skeleton()
LEG_JOINTS = {SKEL.index(n) for leg in LEGS for n in leg[:3]}


def walk(bandai_clip, frames=121):
    m = read_bvh(bandai_clip)
    return replace(m, rotations=m.rotations[:frames], root_positions=m.root_positions[:frames])


def positions(m, rot=None, root=None):
    rot = m.rotations if rot is None else rot
    root = m.root_positions if root is None else root
    return fk(rot.astype(np.float64), root.astype(np.float64), m.skeleton.parents, m.skeleton.offsets)[1]


def test_planted_needs_both_keys_low_and_still_and_no_cut():
    ankles = np.zeros((4, 2, 3))
    ankles[:, 1, 0] = [0.0, 30.0, 60.0, 90.0]  # the right foot steps 30 cm a gap
    ankles[2, 0, 1] = PLANT_HEIGHT_CM + 1  # the left lifts at key 2
    ankles[3, 0, 0] = PLANT_TRAVEL_CM - 1  # ... and comes down a little further on
    got = planted(ankles)
    assert got[:, 0].tolist() == [True, False, False]
    assert not got[:, 1].any()
    ankles[2, 0, 1] = 0.0
    assert planted(ankles)[:, 0].tolist() == [True, True, True]
    assert planted(ankles, [(1, 2)])[:, 0].tolist() == [True, False, True]
    ankles[3, 0, 0] = PLANT_TRAVEL_CM + 1
    assert planted(ankles)[:, 0].tolist() == [True, True, False]


def test_a_walk_keyed_every_10_keeps_its_planted_feet_closer_to_the_capture(bandai_clip):
    m = walk(bandai_clip)
    keys = np.arange(0, 121, 10)
    curve = spline_motion(m, keys, CURVE)
    out = plant_feet(curve, keys, model_feet(SKEL))
    assert np.array_equal(out.rotations[keys], m.rotations[keys])
    assert np.array_equal(out.root_positions, curve.root_positions)
    changed = {int(j) for j in np.flatnonzero((out.rotations != curve.rotations).any(axis=(0, 2)))}
    assert changed and changed <= LEG_JOINTS
    true, before, after = positions(m), positions(curve), positions(out)
    between = np.setdiff1d(np.arange(121), keys)
    err = lambda p, f, j: np.linalg.norm(p[f][:, j] - true[f][:, j], axis=-1).mean()  # noqa: E731
    everything = np.arange(len(SKEL.names))
    assert err(after, between, everything) < err(before, between, everything)
    ankles = [SKEL.index(leg[2]) for leg in LEGS]
    gaps = planted(true[keys][:, ankles])
    assert 2 <= gaps.sum() < gaps.size  # this walk plants a foot in some gaps, not in all
    for g, li in np.argwhere(gaps):  # the planted leg's joints, 15-27 % closer in each
        frames, leg = np.arange(keys[g] + 1, keys[g + 1]), [SKEL.index(n) for n in LEGS[li]]
        assert err(after, frames, leg) < 0.9 * err(before, frames, leg)
    # A planted ankle lies on the line between its keys' ankles.
    g, li = np.argwhere(gaps)[0]
    a, b = keys[g], keys[g + 1]
    j = ankles[li]
    line = np.linspace(true[a, j], true[b, j], b - a + 1)
    np.testing.assert_allclose(after[a : b + 1, j], line, atol=0.05)
    assert np.abs(before[a : b + 1, j] - line).max() > 0.05


def test_a_foot_lifted_at_every_key_leaves_the_curve_as_it_is(bandai_clip):
    m = walk(bandai_clip, 31)
    keys = np.array([0, 15, 30])
    rot = m.rotations.copy()
    root = m.root_positions.copy()
    root[15, 1] += 3 * PLANT_HEIGHT_CM  # a jump at the middle key: no foot is low there
    m = replace(m, rotations=rot, root_positions=root)
    curve = spline_motion(m, keys, CURVE)
    assert plant_feet(curve, keys, model_feet(SKEL)) is curve


def test_a_z_up_rig_in_metres_plants_as_the_same_motion_y_up(bandai_clip):
    m = walk(bandai_clip, 61)
    keys = np.arange(0, 61, 10)
    to_z_up = Rotation.from_euler("x", 90, degrees=True)  # Y up -> Z up
    z_skel = Skeleton(SKEL.names, SKEL.parents, SKEL.offsets / 100.0, "Z", 1.0)
    rot = m.rotations.copy()
    rot[:, 0] = (to_z_up * Rotation.from_quat(rot[:, 0])).as_quat()
    z = replace(m, skeleton=z_skel, rotations=rot, root_positions=to_z_up.apply(m.root_positions) / 100.0)
    curve = spline_motion(m, keys, CURVE)
    # The same curve, turned (a clamped spline's slopes depend on the axes it is drawn in).
    turned = curve.rotations.copy()
    turned[:, 0] = (to_z_up * Rotation.from_quat(turned[:, 0])).as_quat()
    z_curve = replace(z, rotations=turned, root_positions=to_z_up.apply(curve.root_positions) / 100.0)
    y_out = plant_feet(curve, keys, model_feet(SKEL))
    z_out = plant_feet(z_curve, keys, model_feet(z_skel))
    legs = sorted(LEG_JOINTS)
    dots = np.abs((y_out.rotations[:, legs] * z_out.rotations[:, legs]).sum(-1))
    assert dots.min() > 1 - 1e-5  # the same leg rotations, either quaternion sign
    assert not np.array_equal(y_out.rotations, curve.rotations)


def test_feet_of_takes_only_hip_knee_ankle_chains():
    legs = [tuple(SKEL.index(n) for n in leg) for leg in LEGS]
    assert model_feet(SKEL).legs == tuple(legs)
    no_toe = [(*leg[:3], None) for leg in legs]
    assert [leg[3] for leg in feet_of(SKEL, no_toe).legs] == [leg[2] for leg in legs]
    broken = [(legs[0][0], legs[0][2], legs[0][1], legs[0][3]), legs[1]]  # knee and ankle swapped
    assert feet_of(SKEL, broken) is None
    hip_root = Skeleton(("hip", "knee", "ankle"), np.array([-1, 0, 1]), np.zeros((3, 3)))
    assert feet_of(hip_root, [(0, 1, 2, None)]) is None  # turned with the body: not a leg to plant
    assert feet_of(SKEL, [(None, *legs[0][1:]), legs[1]]) is None
    other = Skeleton(("a", "b"), np.array([-1, 0]), np.zeros((2, 3)))
    assert model_feet(other) is None
    # A rig whose shin is a stand-in joint on the knee (zero length): no triangle for the IK.
    offsets = SKEL.offsets.copy()
    offsets[legs[1][2]] = 0.0
    flat = Skeleton(SKEL.names, SKEL.parents, offsets)
    assert model_feet(flat) is None
    offsets[legs[1][2]] = [0.0, -0.5, 0.0]  # 0.5 cm
    assert model_feet(Skeleton(SKEL.names, SKEL.parents, offsets)) is None


def test_only_the_trusted_curve_plants(bandai_clip):
    m = walk(bandai_clip, 61)
    keys = np.arange(0, 61, 10)
    assert not SplineInbetweener(SKEL, method=CURVE).plant
    plain = SplineInbetweener(SKEL, method=CURVE).fill(m, keys)
    curve = trusted_curve(SKEL)
    held = curve.fill(m, keys)
    assert np.array_equal(plain.rotations, spline_motion(m, keys, CURVE).rotations)
    assert not np.array_equal(held.rotations, plain.rotations)
    # A caller that found no legs to hold (a rig's, solve.rig_feet) gets the curve as it is,
    # even where the joints carry the model's names.
    assert np.array_equal(curve.fill(m, keys, feet=None).rotations, plain.rotations)
    # Windows (the trusted fill's probes) plant window by window, as fill does.
    rot, root = curve.fill_batch(m.rotations[None], m.root_positions[None], keys)
    np.testing.assert_allclose(rot[0], held.rotations, atol=1e-6)
    np.testing.assert_array_equal(root[0], held.root_positions)


def test_ik_leaves_a_straight_leg_straight():
    # A leg straighter than the IK's reach bound, asked to hold its own ankle: no knee bend.
    skel = Skeleton(("hip0", "hip", "knee", "ankle", "toe"), np.array([-1, 0, 1, 2, 3]),
                    np.array([[0, 100, 0], [10, 0, 0], [0, -45, 0], [0, -45, 0], [0, -5, 10]]))  # fmt: skip
    rot = np.tile(np.array([0, 0, 0, 1.0]), (3, 5, 1))
    root = np.zeros((3, 3))
    _, pos = fk(rot, root, skel.parents, skel.offsets)
    out = two_bone_ik(rot, root, skel, (1, 2, 3, 4), pos[:, 3], np.ones(3))
    _, new = fk(out, root, skel.parents, skel.offsets)
    np.testing.assert_allclose(new[:, 2], pos[:, 2], atol=1e-6)


def test_a_leg_the_ik_cannot_pose_keeps_the_curve(bandai_clip, monkeypatch):
    from pipeline.infer import post

    m = walk(bandai_clip, 61)
    keys = np.arange(0, 61, 10)
    curve = spline_motion(m, keys, CURVE)
    monkeypatch.setattr(post, "lock_feet", lambda rot, *a, **k: np.full_like(rot, np.nan))
    assert plant_feet(curve, keys, model_feet(SKEL)) is curve  # never NaN in a fill


def _with_roll_joints(skel, motion):
    """``skel`` and ``motion`` with a joint inserted halfway along each thigh and shin (a rig's
    roll joints in the chain, at rest), the same world motion."""
    names, parents, offsets, old_of = [], [], [], []
    new_index = {}
    inserted = {SKEL.index(n) for leg in LEGS for n in leg[1:3]}  # knees and ankles
    for j, name in enumerate(skel.names):
        p = skel.parents[j]
        parent = new_index.get(p, -1)
        off = skel.offsets[j].astype(np.float64)
        if j in inserted:
            names.append(f"{name}_roll")
            parents.append(parent)
            offsets.append(off / 2)
            old_of.append(None)
            parent, off = len(names) - 1, off / 2
        new_index[j] = len(names)
        names.append(name)
        parents.append(parent)
        offsets.append(off)
        old_of.append(j)
    rolled = Skeleton(tuple(names), np.array(parents), np.array(offsets, np.float32))
    rot = np.tile(np.array([0, 0, 0, 1.0], np.float32), (len(motion.rotations), len(names), 1))
    for k, j in enumerate(old_of):
        if j is not None:
            rot[:, k] = motion.rotations[:, j]
    return (
        rolled,
        replace(motion, skeleton=rolled, rotations=rot),
        [new_index[j] for j in range(len(skel.names))],
    )


def test_roll_joints_in_the_leg_plant_as_the_leg_without_them(bandai_clip):
    m = walk(bandai_clip, 61)
    keys = np.arange(0, 61, 10)
    rolled, r_motion, old_at = _with_roll_joints(SKEL, m)
    np.testing.assert_allclose(positions(r_motion)[:, old_at], positions(m), atol=1e-3)  # one motion
    plain = plant_feet(spline_motion(m, keys, CURVE), keys, model_feet(SKEL))
    rolled_out = plant_feet(spline_motion(r_motion, keys, CURVE), keys, model_feet(rolled))
    assert not np.array_equal(plain.rotations, spline_motion(m, keys, CURVE).rotations)
    np.testing.assert_allclose(positions(rolled_out)[:, old_at], positions(plain), atol=1e-3)
    rolls = [i for i, n in enumerate(rolled.names) if n.endswith("_roll")]
    assert np.array_equal(rolled_out.rotations[:, rolls], r_motion.rotations[:, rolls])  # kept at rest


def test_blocks_from_key_to_key_give_what_the_whole_shot_gives(bandai_clip, monkeypatch):
    from pipeline.infer import plant

    m = walk(bandai_clip, 121)
    keys = np.arange(0, 121, 5)  # runs of up to six gaps with a foot held
    curve = spline_motion(m, keys, CURVE)
    whole = plant_feet(curve, keys, model_feet(SKEL)).rotations
    monkeypatch.setattr(plant, "PLANT_BLOCK", 12)  # those runs cut into blocks of two gaps
    assert np.array_equal(plant_feet(curve, keys, model_feet(SKEL)).rotations, whole)
    assert not np.array_equal(whole, curve.rotations)
    held = np.array([True, True, False, True, True, True, False])
    assert plant._blocks(np.arange(0, 80, 10), held, 20) == [(0, 2), (3, 5), (5, 6)]
    assert plant._blocks(np.arange(0, 80, 10), held, 10**6) == [(0, 2), (3, 6)]
    assert plant._blocks(np.array([0, 50, 60]), np.array([True, True]), 20) == [(0, 1), (1, 2)]
