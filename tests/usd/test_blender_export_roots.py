"""A real Blender 5.0.1 export (``bpy.ops.wm.usd_export``, tests/fixtures/blender/ik_roots.usda):
an armature of the model's joint names plus an animator's two unparented, non-deforming IK
controls (``foot_ik_L`` and its pole ``knee_pole_L``), keyed every 10 frames and sampled by
Blender on every frame. Blender writes them as a skeleton of three root joints. The fill fills the body between the
keys and keeps the keys bit for bit; the IK target, on the left ankle at every key, follows the
filled ankle between them (tests/usd/test_follow_controls.py measures how closely), and the
pole, on no joint, keeps its authored values at every time written; one warning says so. The
review stage poses the filled animation.
The layer's ``doc`` says how the file was made; no Blender is needed here."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from usd_fixtures import digest, layer_samples, tween

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "blender" / "ik_roots.usda"
SKEL = "/root/Armature/Armature"
ANIM = f"{SKEL}/ArmatureAction"
FILLED = f"{ANIM}_tween"
KEYS = [float(k) for k in range(1, 62, 10)]
IK = ["foot_ik_L", "knee_pole_L"]
ATTRS = ("rotations", "translations", "scales")


def _angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Degrees between two arrays of unit quaternions (q and -q are one rotation)."""
    return np.degrees(2 * np.arccos(np.clip(np.abs((a * b).sum(-1)), 0.0, 1.0)))


@pytest.mark.parametrize("model", ["interp", "default"])
def test_a_blender_export_with_ik_controls_fills_the_body_and_keeps_the_controls(
    tmp_path, monkeypatch, capsys, model
):
    from pxr import Usd, UsdSkel

    shot = tmp_path / "ik_roots.usda"
    shutil.copyfile(FIXTURE, shot)
    before = digest(shot)
    stage = Usd.Stage.Open(str(shot))
    joints = list(stage.GetPrimAtPath(SKEL).GetAttribute("joints").Get())
    topo = UsdSkel.Topology(joints)
    assert topo.Validate()[0]
    roots = [joints[j] for j, p in enumerate(topo.GetParentIndices()) if p < 0]
    assert roots == ["Hips", *IK]  # as Blender writes unparented bones: roots of their own
    src = stage.GetPrimAtPath(ANIM)
    assert list(src.GetAttribute("joints").Get()) == joints
    assert src.GetAttribute("rotations").GetTimeSamples() == [float(t) for t in range(1, 62)]

    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--keys", "1-61x10", "--model", model)
    assert rc == 0, err
    assert "error" not in err and "Traceback" not in err, err
    warnings = [ln for ln in err.splitlines() if ln.startswith("tween: warning: ")]
    assert len(warnings) == 1, err
    assert warnings[0].startswith(
        f"tween: warning: {shot} {SKEL}: 3 root joints ('Hips', 'foot_ik_L', 'knee_pole_L'): "
        "the character is the hierarchy under 'Hips' (21 joints); the 2 joints under the other "
        "roots (the first is 'foot_ik_L') are not filled: between the keys 'foot_ik_L' follows "
        "the filled 'Foot_L'; 'knee_pole_L' stays as authored"
    ), err
    assert digest(shot) == before  # the animator's file is never written

    got, filled = layer_samples(tmp_path / "ik_roots.tween.v001.usda", FILLED, ATTRS)
    assert got == joints
    ik, body = [joints.index(n) for n in IK], [j for j, n in enumerate(joints) if n not in IK]
    target, pole = ik
    for name in ATTRS:
        attr = src.GetAttribute(name)
        assert sorted(filled[name]) == [float(t) for t in range(1, 62)], name
        for t, v in filled[name].items():
            authored = np.array(attr.Get(t))
            # The pole: Blender's values at every time, bit for bit; the target's scale too.
            assert np.array_equal(v[pole], authored[pole]), (name, t)
            if name == "scales":
                assert np.array_equal(v[target], authored[target]), t
            if t in KEYS:  # keys bit for bit, every joint
                assert np.array_equal(v, authored), (name, t)
    # Between the keys the target moves with the filled ankle, off Blender's path.
    tr_src = src.GetAttribute("translations")
    moved = [t for t in filled["translations"] if t not in KEYS]
    assert all(
        not np.array_equal(filled["translations"][t][target], np.array(tr_src.Get(t))[target]) for t in moved
    )
    # Between the keys the body is the fill's, not Blender's Bezier, and it moves (no hold).
    rot, rot_src = filled["rotations"], src.GetAttribute("rotations")
    between = [t for t in rot if t not in KEYS]
    off = max(_angles(rot[t][body], np.array(rot_src.Get(t))[body]).max() for t in between)
    assert off > 1.0, off
    assert _angles(rot[16.0][body], rot[11.0][body]).max() > 1.0
    assert _angles(rot[16.0][body], rot[21.0][body]).max() > 1.0

    # The review stage poses the filled animation, IK controls included (a viewer's reading).
    review = Usd.Stage.Open(str(tmp_path / "ik_roots.review.v001.usda"))
    cache = UsdSkel.Cache()
    cache.Populate(UsdSkel.Root(review.GetPrimAtPath("/root/Armature")), Usd.PrimDefaultPredicate)
    query = cache.GetSkelQuery(UsdSkel.Skeleton(review.GetPrimAtPath(SKEL)))
    assert query.GetAnimQuery().GetPrim().GetPath() == FILLED
    mats = np.array(query.ComputeJointLocalTransforms(Usd.TimeCode(16.0)))
    tr = filled["translations"][16.0]
    assert np.allclose(mats[:, 3, :3], tr, atol=1e-5)
    assert not np.allclose(tr[body], np.array(src.GetAttribute("translations").Get(16.0))[body])
