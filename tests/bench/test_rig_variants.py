"""Same motion, any rig: variant rigs of one clip reach the network identically and fill alike."""

import json

import numpy as np
import pytest
from usd_fixtures import BANDAI_CLIP

from pipeline.adapt.mapping import MODEL_JOINTS
from pipeline.adapt.retarget import typical_local
from pipeline.bench import blocking
from pipeline.bench import rig_variants as rv
from pipeline.fill.api import FillOptions, fill_shot
from pipeline.motion.bvh import read_bvh
from pipeline.motion.rotations import quat_apply, quat_mul


@pytest.fixture(scope="module")
def clip():
    return read_bvh(BANDAI_CLIP).slice(0, 61)


@pytest.fixture(scope="module")
def base_input(clip, tmp_path_factory):
    shot = rv.write_rig_shot(rv.model_rig_of(clip), tmp_path_factory.mktemp("base") / "shot.usda")
    return rv.network_input(shot)


@pytest.mark.parametrize("name", rv.VARIANTS)
def test_every_variant_reaches_the_network_as_the_model_rig(name, clip, base_input, tmp_path):
    rig = rv.variant(rv.model_rig_of(clip), name, seed=3)
    local, root, ref = rv.network_input(rv.write_rig_shot(rig, tmp_path / "v.usda"))
    b_local, b_root, b_ref = base_input
    assert b_ref == "model"
    assert np.abs(np.abs((local.astype(np.float64) * b_local).sum(-1)) - 1).max() < 1e-4
    np.testing.assert_allclose(root, b_root, atol=1e-4)
    # Turned frames cannot be told from the bones alone: the rest pose says how, a bind
    # pose as such, the zero pose (Blender's import) as the model's own zero pose.
    want = "model" if "frames" not in name else "zero pose" if "rest:zero" in name else "rest"
    assert ref == want


def test_variants_really_differ_from_the_model_rig(clip):
    """The variants are not the model rig in disguise: names, frames and rests all change."""
    base = rv.model_rig_of(clip)
    assert rv.variant(base, "names:ue5").names[0] == "pelvis"
    fr = rv.variant(base, "frames")
    assert np.abs(np.abs((fr.rot * base.rot).sum(-1)) - 1).max() > 0.05
    assert np.abs(rv.variant(base, "rest:zero").rest_rot[:, 3] - 1).max() == 0
    assert len(rv.variant(base, "extra:fingers").names) == 21 + 30


def test_the_canonical_reference_alone_was_not_rig_independent(clip, tmp_path):
    """Mapping a renamed copy through the canonical reference of its rest pose (all the
    retargeter did before) changes what the network sees; the model-frames check is what
    removes the difference."""
    from pipeline.adapt.retarget import reference_pose
    from pipeline.fill.plan import make_plan
    from pipeline.motion.rotations import quat_inv, quat_mul
    from pipeline.usd.read import anim_values, to_skeleton_order

    # The rest pose older conversions wrote: the canonical pose of the clip's first frame.
    rig = rv.variant(rv.model_rig_of(clip), "names:mixamo")
    g, p = clip.slice(0, 1).fk()
    roles = {n: i for i, n in enumerate(clip.skeleton.names)}
    ref = reference_pose(roles, g[0].astype(np.float64), p[0].astype(np.float64))
    rig.rest_rot = np.stack(
        [ref[j] if q < 0 else quat_mul(quat_inv(ref[q]), ref[j]) for j, q in enumerate(rig.parents)]
    )
    shot = rv.write_rig_shot(rig, tmp_path / "m.usda")
    plan = make_plan(str(shot), None, None, None, 30.0)
    cp = plan.chars[0]
    rt, c = cp.retarget, cp.char
    assert rt.reference == "model"
    rot, tr, _ = anim_values(plan.shot.stage, c, cp.keys)
    r, t = to_skeleton_order(c, rot, tr)
    want, _ = rt.to_model(r, t)
    pos = rt.s * c.bind_pos @ rt.R.T + rt.t
    rt.src_ref = reference_pose(
        rt.roles, quat_mul(np.broadcast_to(rt.q_R, c.bind_rot.shape), c.bind_rot), pos
    )
    got, _ = rt.to_model(r, t)
    assert np.abs(np.abs((got.astype(np.float64) * want).sum(-1)) - 1).max() > 1e-3


def test_fill_on_variant_rigs_is_within_two_percent(clip, capfd):
    res = rv.run_rig_bench(
        [clip], variants=("names:ue5", "frames", "rest:zero", "all:ue5+frames+z-up+metres+twist"),
        methods=("model", "interp"),
    )  # fmt: skip
    for v, r in res["ratio_to_model_skeleton"].items():
        assert abs(r["model"] - 1) < 0.02, (v, r)
        assert abs(r["interp"] - 1) < 0.02, (v, r)
    # The model is really filling: far better than interpolation on this walk.
    assert res["error_cm"]["model skeleton"]["model"] < 0.5 * res["error_cm"]["model skeleton"]["interp"]
    assert "| frames | rest |" in res["markdown"]


def _blender_like(clip, tmp_path):
    """What Blender writes for an imported BVH: bone-aligned joint frames, the BVH zero pose
    (every bone along its offset) as rest, Z up, metres."""
    rig = rv.variant(rv.model_rig_of(clip), "all:rest:zero+frames+z-up+metres")
    return rig, rv.write_rig_shot(rig, tmp_path / "blender.usda")


def test_blender_zero_pose_rest_fills_through_the_model_zero_pose(clip, base_input, tmp_path):
    rig, shot = _blender_like(clip, tmp_path)
    local, _, ref = rv.network_input(shot)
    assert ref == "zero pose"
    assert np.abs(np.abs((local.astype(np.float64) * base_input[0]).sum(-1)) - 1).max() < 1e-4
    res = fill_shot(str(shot), FillOptions(out_dir=str(tmp_path / "o")))
    from pxr import Usd

    stage = Usd.Stage.Open(res["review"])
    anim = stage.GetPrimAtPath("/World/Character/Skel/Anim_tween")
    assert anim.GetAttribute("tween:retargetReference").Get() == "zero pose"


def test_a_rest_pose_that_is_no_pose_falls_back_to_a_standing_key(clip, tmp_path):
    """A rig on other frames whose rest pose is neither a bind pose nor the model's zero
    pose (here: every joint turned at random) is filled from its most upright key."""
    from scipy.spatial.transform import Rotation

    rig = rv.variant(rv.model_rig_of(clip), "all:daz+frames")
    rig.rest_rot = Rotation.random(len(rig.names), random_state=1).as_quat()
    shot = rv.write_rig_shot(rig, tmp_path / "odd.usda")
    _, _, ref = rv.network_input(shot)
    assert ref.startswith("key ")
    fill_shot(str(shot), FillOptions(out_dir=str(tmp_path / "o")))


def test_rig_without_hands_and_toes_fills_and_says_so(clip, tmp_path, capfd):
    from pxr import Usd

    rig = rv.variant(rv.model_rig_of(clip), "names:ue5")
    rig = _collapsed(rig, [n for n in rig.names if n.startswith(("hand_", "ball_"))])
    shot = rv.write_rig_shot(rig, tmp_path / "nohands.usda")
    res = fill_shot(str(shot), FillOptions(out_dir=str(tmp_path / "o")))
    err = capfd.readouterr().err
    assert "the rig has no Hand_L, Hand_R, Toes_L, Toes_R: held at the model's typical pose" in err
    stage = Usd.Stage.Open(res["review"])
    anim = stage.GetPrimAtPath("/World/Character/Skel/Anim_tween")
    assert list(anim.GetAttribute("tween:missingJoints").Get()) == ["Hand_L", "Hand_R", "Toes_L", "Toes_R"]


def _collapsed(rig: rv.Rig, names) -> rv.Rig:
    """The rig without the joints ``names``: each child of one takes on its transform, so
    every remaining joint moves in the world exactly as before."""
    rot, trans = rig.rot.copy(), rig.trans.copy()
    rest_rot, rest_trans = rig.rest_rot.copy(), rig.rest_trans.copy()
    parents = rig.parents.copy()
    for name in names:
        j = rig.names.index(name)
        for c in np.flatnonzero(parents == j):
            for r, t in ((rot, trans), (rest_rot, rest_trans)):
                t[..., c, :] = t[..., j, :] + quat_apply(r[..., j, :], t[..., c, :])
                r[..., c, :] = quat_mul(r[..., j, :], r[..., c, :])
            parents[c] = parents[j]
    keep = [i for i, n in enumerate(rig.names) if n not in names]
    idx = {old: k for k, old in enumerate(keep)}
    return rv.Rig([rig.names[i] for i in keep], np.array([idx.get(parents[i], -1) for i in keep]),
                  rest_rot[keep], rest_trans[keep], rot[:, keep], trans[:, keep])  # fmt: skip


@pytest.mark.parametrize("source", sorted(blocking.MISSING))
def test_a_rig_lacking_joints_reaches_the_network_as_the_blocking_bench_says(source, clip, tmp_path, capfd):
    """A rig without clavicles (or with one spine joint fewer) reaches the network with the
    joints it lacks in the model's typical pose and every other joint turned as in the world:
    exactly what the blocking bench's ``noshoulders`` / ``nospine`` sources give the fill."""
    names = blocking.MISSING[source]
    rig = _collapsed(rv.model_rig_of(clip), names)
    local, root, ref = rv.network_input(rv.write_rig_shot(rig, tmp_path / f"{source}.usda"))
    assert ref == "rest"
    keys = np.arange(0, len(clip), 10)
    want = blocking.without_joints(clip.rotations[keys].astype(np.float64), names)
    assert local.shape == want.shape
    assert np.abs(np.abs((local.astype(np.float64) * want).sum(-1)) - 1).max() < 1e-5
    np.testing.assert_allclose(root, clip.root_positions[keys], atol=1e-3)
    typical = typical_local()
    for n in names:  # the typical pose, not the reference's T-pose (16° from the mean clavicle)
        j = MODEL_JOINTS.index(n)
        assert np.abs(np.abs(local[:, j].astype(np.float64) @ typical[j]) - 1).max() < 1e-6
    res = fill_shot(
        str(rv.write_rig_shot(rig, tmp_path / "fill.usda")), FillOptions(out_dir=str(tmp_path / "o"))
    )
    assert f"the rig has no {', '.join(names)}: held at the model's typical pose" in capfd.readouterr().err
    assert res["review"]


def test_bench_cli_rig_variants(tmp_path):
    from typer.testing import CliRunner

    from pipeline.cli import app

    r = CliRunner().invoke(app, ["bench", "--rig-variants", "--limit", "1", "--methods", "interp",
                                 "--out", str(tmp_path / "b")])  # fmt: skip
    assert r.exit_code == 0, r.output
    res = json.loads((tmp_path / "b" / "rig_bench.json").read_text())
    assert set(res["error_cm"]) == {"model skeleton", *rv.VARIANTS}
    assert all(abs(v["interp"] - 1) < 1e-6 for v in res["ratio_to_model_skeleton"].values())
    r = CliRunner().invoke(app, ["bench", "--rig-variants", "--methods", "zero"])
    assert r.exit_code != 0 and "the rig bench runs" in str(r.exception)


def test_skeleton_outside_any_skelroot_is_filled(clip, tmp_path):
    """Blender exports an armature without a skinned mesh as a Skeleton under plain Xforms,
    its animation bound by skel:animationSource: it is read and filled."""
    from pxr import Usd

    rig = rv.variant(rv.model_rig_of(clip), "all:rest:zero+frames+z-up+metres")
    shot = rv.write_rig_shot(rig, tmp_path / "blender.usda")
    stage = Usd.Stage.Open(str(shot))
    prim = stage.GetPrimAtPath("/World/Character")
    prim.SetTypeName("Xform")
    prim.RemoveAPI(__import__("pxr").UsdSkel.BindingAPI)
    stage.GetRootLayer().Save()
    res = fill_shot(str(shot), FillOptions(out_dir=str(tmp_path / "o")))
    assert res["retarget"] == {"/World/Character/Skel/Anim": {"reference": "zero pose", "missing": []}}
