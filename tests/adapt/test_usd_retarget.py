"""Retargeting through the rest pose: other rest orientations, units, up axis, several characters."""

import json

import numpy as np
from scipy.spatial.transform import Rotation
from usd_fixtures import BANDAI_CLIP, bandai_shot, cmu_shot, samples

from pipeline.adapt.mapping import map_joints
from pipeline.adapt.retarget import Retarget
from pipeline.data.skeletons import bandai_skeleton
from pipeline.fill.api import FillOptions, fill_shot, validate_shot
from pipeline.fill.solve import to_skeleton_order
from pipeline.motion.bvh import read_bvh
from pipeline.motion.clip import Motion
from pipeline.motion.rotations import quat_apply, quat_inv, quat_mul
from pipeline.motion.skeleton import Skeleton
from pipeline.usd.read import anim_values, read_shot

MIXAMO = {"Hips": "Hips", "Spine": "Spine", "Chest": "Spine2", "Neck": "Neck", "Head": "Head"}
for _s, _side in (("L", "Left"), ("R", "Right")):
    MIXAMO.update({f"Shoulder_{_s}": f"{_side}Shoulder", f"UpperArm_{_s}": f"{_side}Arm",
                   f"LowerArm_{_s}": f"{_side}ForeArm", f"Hand_{_s}": f"{_side}Hand",
                   f"UpperLeg_{_s}": f"{_side}UpLeg", f"LowerLeg_{_s}": f"{_side}Leg",
                   f"Foot_{_s}": f"{_side}Foot", f"Toes_{_s}": f"{_side}ToeBase"})  # fmt: skip


def _reframe(q, parents, R):
    """Local rotations of the same world pose on joints whose frames are rotated by R."""
    Rp = np.stack([R[p] if p >= 0 else np.array([0, 0, 0, 1.0]) for p in parents])
    return quat_mul(quat_mul(quat_inv(Rp), q.astype(np.float64)), R)


def test_rig_with_other_rest_orientations_units_and_up_axis_maps_exactly(tmp_path):
    from pxr import Gf, Usd, Vt

    from pipeline.usd.convert import write_shot

    src = read_bvh(BANDAI_CLIP).slice(0, 41)
    sk = bandai_skeleton()
    R = Rotation.random(len(sk), random_state=3).as_quat()
    Rp = np.stack([R[p] if p >= 0 else np.array([0, 0, 0, 1.0]) for p in sk.parents])
    offsets = quat_apply(quat_inv(Rp), sk.offsets.astype(np.float64)) * 0.01  # metres, parent's new frame
    rig = Skeleton(tuple("mixamorig_" + MIXAMO[n] for n in sk.names), sk.parents, offsets, "Y", 1.0)
    rot = _reframe(src.rotations, sk.parents, R).astype(np.float32)
    m = Motion(rig, rot, src.root_positions * 0.01, 30, "reframed")
    path = write_shot(m, tmp_path / "rig.usda", keys_every=10, up_axis="Z")
    # Rest/bind pose: the model's own standing pose, on the rotated frames.
    stand = json.loads(open("pipeline/adapt/bandai_stand.json").read())["rotations_xyzw"]
    q_st = _reframe(np.array([stand[n] for n in sk.names]), sk.parents, R)
    stage = Usd.Stage.Open(str(path))
    skel = stage.GetPrimAtPath("/World/Character/Skel")
    g, p = np.zeros((len(sk), 4)), np.zeros((len(sk), 3))
    rest, bind = [], []
    for j, par in enumerate(sk.parents):
        t = offsets[j] if par >= 0 else np.array([0, 0.93, 0])
        g[j] = q_st[j] if par < 0 else quat_mul(g[par], q_st[j])
        p[j] = t if par < 0 else p[par] + quat_apply(g[par], t)
        for out, q, v in ((rest, q_st[j], t), (bind, g[j], p[j])):
            out.append(
                Gf.Matrix4d(Gf.Rotation(Gf.Quatd(float(q[3]), *map(float, q[:3]))), Gf.Vec3d(*map(float, v)))
            )
    skel.GetAttribute("restTransforms").Set(Vt.Matrix4dArray(rest))
    skel.GetAttribute("bindTransforms").Set(Vt.Matrix4dArray(bind))
    stage.GetRootLayer().Save()

    shot = read_shot(path)
    c = shot.characters[0]
    assert shot.meters_per_unit == 1.0 and shot.up_axis == "Z"
    rt = Retarget(c, map_joints(c.joints, c.parents), shot.up_axis, shot.meters_per_unit)
    assert not rt.direct and abs(rt.ratio - 1) < 1e-6
    r, t, _ = anim_values(shot.stage, c, c.sample_times)
    local, root = rt.to_model(*to_skeleton_order(c, r, t))
    keys = np.arange(0, 41, 10)
    want = src.rotations[keys]
    assert np.abs(np.abs((local * want).sum(-1)) - 1).max() < 1e-5
    np.testing.assert_allclose(root, src.root_positions[keys], atol=1e-3)
    # And back: model → rig gives the rig's own values.
    r2, t2 = rt.from_model(local, root, *to_skeleton_order(c, r, t))
    assert np.abs(np.abs((r2 * r).sum(-1)) - 1).max() < 1e-5
    np.testing.assert_allclose(t2, t, atol=1e-5)


def test_several_characters_filled_independently_with_takes(tmp_path):
    from pxr import Sdf, Usd, UsdUtils

    a = bandai_shot(tmp_path / "a.usda", frames=41, keys_every=10, fps=60, name="Walker")
    # A Y-up stage: its up axis comes from the root layer, so every character in it is Y up.
    cmu_shot(tmp_path / "b.usda", frames=81, keys_every=16, up_axis="Y", name="Dancer")
    root = Sdf.Layer.CreateNew(str(tmp_path / "sh020.usda"))
    UsdUtils.CopyLayerMetadata(Sdf.Layer.FindOrOpen(str(a)), root, True, True)
    root.endTimeCode = 1081
    root.subLayerPaths = ["a.usda", "b.usda"]
    root.Save()
    o = FillOptions(model="interp", out_dir=str(tmp_path / "o"), takes=2)
    s = validate_shot(str(tmp_path / "sh020.usda"), o)
    assert sorted(s["characters"]) == ["/World/Dancer/Skel/Anim", "/World/Walker/Skel/Anim"]
    res = fill_shot(str(tmp_path / "sh020.usda"), o)
    stage = Usd.Stage.Open(res["review"])
    for name, n_keys in (("Walker", 9), ("Dancer", 6)):
        orig = samples(stage, f"/World/{name}/Skel/Anim")
        filled = samples(stage, f"/World/{name}/Skel/Anim_tween")
        assert len(orig) == n_keys and len(filled) == 81
        for t, v in orig.items():
            assert np.array_equal(filled[t], v)
    vs = stage.GetPrimAtPath("/World").GetVariantSets().GetVariantSet("tweenTake")
    vs.SetVariantSelection("take1")
    assert stage.GetPrimAtPath("/World/Dancer/Skel/Anim_tween").GetAttribute("tween:take").Get() == 1
    assert len(samples(stage, "/World/Dancer/Skel/Anim_tween")) == 81


def test_skeletons_sharing_an_animation_share_one_fill(tmp_path):
    """Two characters bound to one animation (a crowd on one cycle): filled once, listed once,
    both rebound to the fill (each was filled again, and its fill written over the last)."""
    from pxr import Sdf, Usd, UsdSkel

    shot = bandai_shot(tmp_path / "sh030.usda", frames=41, keys_every=10, name="Walker")
    layer = Sdf.Layer.FindOrOpen(str(shot))
    assert Sdf.CopySpec(layer, "/World/Walker", layer, "/World/Twin")
    stage = Usd.Stage.Open(layer)
    stage.RemovePrim("/World/Twin/Skel/Anim")
    UsdSkel.BindingAPI(stage.GetPrimAtPath("/World/Twin/Skel")).GetAnimationSourceRel().SetTargets(
        ["/World/Walker/Skel/Anim"]
    )
    layer.Save()
    o = FillOptions(model="interp", out_dir=str(tmp_path / "o"), takes=2)
    s = validate_shot(str(shot), o)
    assert s["characters"] == ["/World/Walker/Skel/Anim"]
    assert s["skeletons"] == {"/World/Walker/Skel/Anim": ["/World/Walker/Skel", "/World/Twin/Skel"]}
    res = fill_shot(str(shot), o)
    assert res["characters"] == ["/World/Walker/Skel/Anim"]
    assert res["skeletons"] == {"/World/Walker/Skel/Anim": ["/World/Walker/Skel", "/World/Twin/Skel"]}
    review = Usd.Stage.Open(res["review"])
    cache = UsdSkel.Cache()
    for skel in ("/World/Walker/Skel", "/World/Twin/Skel"):
        query = cache.GetSkelQuery(UsdSkel.Skeleton(review.GetPrimAtPath(skel)))
        assert str(query.GetAnimQuery().GetPrim().GetPath()) == "/World/Walker/Skel/Anim_tween", skel
    assert not review.GetPrimAtPath("/World/Twin/Skel/Anim_tween")


def test_tween_key_times_attribute_overrides_the_samples(tmp_path):
    from pxr import Sdf, Usd, Vt

    shot = bandai_shot(tmp_path / "kt.usda", frames=41, keys_every=5)
    stage = Usd.Stage.Open(str(shot))
    prim = stage.GetPrimAtPath("/World/Character/Skel/Anim")
    prim.ApplyAPI("TweenAPI")
    prim.GetAttribute("tween:keyTimes").Set(Vt.DoubleArray([1001, 1021, 1041]))
    stage.GetRootLayer().Save()
    s = validate_shot(str(shot), FillOptions(model="interp"))
    assert s["keys"]["/World/Character/Skel/Anim"] == [1001.0, 1021.0, 1041.0]
    # --keys wins over the attribute.
    s = validate_shot(str(shot), FillOptions(model="interp", keys="1001-1041x10"))
    assert s["keys"]["/World/Character/Skel/Anim"] == [1001.0, 1011.0, 1021.0, 1031.0, 1041.0]
    assert Sdf
