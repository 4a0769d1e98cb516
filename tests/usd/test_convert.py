"""`tween convert`: BVH → UsdSkel shot (skeleton, animation, skinned mannequin), exact round trip."""

import numpy as np
from typer.testing import CliRunner
from usd_fixtures import ANIM, BANDAI_CLIP, CMU_CLIP, bandai_shot

from pipeline.adapt.mapping import map_joints
from pipeline.adapt.retarget import Retarget
from pipeline.fill.solve import to_skeleton_order
from pipeline.motion.bvh import read_bvh
from pipeline.usd.read import anim_values, read_shot


def _motion_from_shot(path):
    shot = read_shot(path)
    c = shot.characters[0]
    rt = Retarget(c, map_joints(c.joints, c.parents), shot.up_axis, shot.meters_per_unit)
    rot, tr, _ = anim_values(shot.stage, c, c.sample_times)
    return shot, rt, rt.to_model(*to_skeleton_order(c, rot, tr))


def test_bvh_usd_motion_round_trip_is_exact(tmp_path):
    src = read_bvh(BANDAI_CLIP)
    path = bandai_shot(tmp_path / "walk.usda", frames=len(src), keys_every=1)
    shot, rt, (rot, root) = _motion_from_shot(path)
    assert rt.direct and rt.identity_frame
    assert shot.tcps == 30 and shot.start == 1001 and shot.end == 1001 + len(src) - 1
    np.testing.assert_array_equal(rot, src.rotations)
    np.testing.assert_array_equal(root, src.root_positions)


def test_keys_every_start_fps_and_skinned_mannequin(tmp_path):
    from pxr import Usd, UsdGeom, UsdSkel

    runner = CliRunner()
    from pipeline.cli import app

    out = tmp_path / "blocked.usda"
    res = runner.invoke(app, ["convert", str(BANDAI_CLIP), str(out), "--keys-every", "8", "--frames", "0-60",
                              "--start", "1001", "--fps", "24"])  # fmt: skip
    assert res.exit_code == 0, res.output
    stage = Usd.Stage.Open(str(out))
    assert stage.GetTimeCodesPerSecond() == 24 and stage.GetStartTimeCode() == 1001
    n = int(np.floor(60 * 24 / 30)) + 1  # 61 source frames at 30 fps → 49 at 24
    assert stage.GetEndTimeCode() == 1001 + n - 1
    times = stage.GetPrimAtPath(ANIM).GetAttribute("rotations").GetTimeSamples()
    assert times == [1001 + k for k in range(0, n, 8)] + ([1001 + n - 1] if (n - 1) % 8 else [])
    # The mannequin is bound to the skeleton and skins: its points move with the animation.
    cache = UsdSkel.Cache()
    root = UsdSkel.Root(stage.GetPrimAtPath("/World/Character"))
    cache.Populate(root, Usd.PrimDefaultPredicate)
    bindings = cache.ComputeSkelBindings(root, Usd.PrimDefaultPredicate)
    assert len(bindings) == 1 and len(bindings[0].GetSkinningTargets()) == 1
    skq = cache.GetSkelQuery(UsdSkel.Skeleton(stage.GetPrimAtPath("/World/Character/Skel")))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Character/Mannequin"))
    sq = cache.GetSkinningQuery(mesh.GetPrim())
    pts = []
    for t in (1001, 1001 + n - 1):
        p = mesh.GetPointsAttr().Get(t)
        assert sq.ComputeSkinnedPoints(skq.ComputeSkinningTransforms(t), p, t)
        pts.append(np.array(p))
    assert np.abs(pts[0] - pts[1]).max() > 5.0  # a walk moves the character by more than 5 cm


def test_cmu_rig_converts_z_up_and_reads_back(tmp_path):
    from pxr import Usd, UsdGeom

    src = read_bvh(CMU_CLIP).slice(0, 30)
    from pipeline.usd.convert import write_shot

    path = write_shot(src, tmp_path / "cmu.usda", keys_every=1, up_axis="Z")
    stage = Usd.Stage.Open(path)
    assert UsdGeom.GetStageUpAxis(stage) == "Z" and stage.GetTimeCodesPerSecond() == 60
    shot, rt, (rot, root) = _motion_from_shot(path)
    c = shot.characters[0]
    assert len(c.joints) == 100 and not rt.direct
    # Values read back exactly; the hips sit at the same height (Y up after the Z-up fix).
    r, t, _ = anim_values(shot.stage, c, c.sample_times)
    np.testing.assert_array_equal(r, src.rotations)
    hips = c.names.index("CC_Base_Hip")
    assert abs(root[0, 1] / rt.ratio - src.root_positions[0, 1]) < 1e-3
    assert hips == 0


def test_bandai_joint_names_are_written_unchanged(tmp_path):
    from pxr import Usd

    from pipeline.usd.convert import SOURCE_NAMES_ATTR, usd_joint_names

    src = read_bvh(BANDAI_CLIP)
    assert usd_joint_names(src.skeleton.names) == list(src.skeleton.names)
    path = bandai_shot(tmp_path / "walk.usda", frames=5, keys_every=1)
    stage = Usd.Stage.Open(str(path))
    skel = stage.GetPrimAtPath("/World/Character/Skel")
    leaf = [t.rsplit("/", 1)[-1] for t in skel.GetAttribute("joints").Get()]
    assert leaf == list(src.skeleton.names)
    assert not skel.GetAttribute(SOURCE_NAMES_ATTR)  # only written when a name had to change


def test_single_joint_clip_gets_a_cube_mannequin(tmp_path):
    from pxr import Usd, UsdGeom

    from pipeline.usd.convert import write_shot

    p = tmp_path / "one.bvh"
    p.write_text(
        "HIERARCHY\nROOT Prop\n{\n  OFFSET 0 0 0\n  CHANNELS 6 Xposition Yposition Zposition "
        "Zrotation Xrotation Yrotation\n  End Site\n  {\n    OFFSET 0 0 0\n  }\n}\n"
        "MOTION\nFrames: 3\nFrame Time: 0.0416667\n0 10 0 0 0 0\n1 10 0 0 5 0\n2 10 0 0 10 0\n"
    )
    out = write_shot(read_bvh(p), tmp_path / "one.usda")
    stage = Usd.Stage.Open(out)
    pts = np.array(UsdGeom.Mesh(stage.GetPrimAtPath("/World/Character/Mannequin")).GetPointsAttr().Get())
    assert pts.shape == (8, 3) and np.isfinite(pts).all()
    assert stage.GetTimeCodesPerSecond() == 24


def test_an_existing_shot_is_replaced_only_with_force(tmp_path):
    import subprocess
    import sys

    out = tmp_path / "sh010.usda"
    out.write_text("#usda 1.0\n# the shot the studio's fill layers sublayer\n")
    before = out.read_bytes()
    cmd = [sys.executable, "-m", "pipeline.cli", "convert", str(BANDAI_CLIP), str(out), "--frames", "0-20"]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert (
        res.returncode == 2
        and res.stderr.count("\n") == 1
        and "--force" in res.stderr
        and str(out) in res.stderr
    )
    assert out.read_bytes() == before
    res = subprocess.run([*cmd, "--force"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert out.read_bytes() != before and res.stdout.strip() == str(out)
