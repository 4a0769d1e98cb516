"""Two skeletons (two characters) bound to one SkelAnimation: the fill fills it once, on the
first skeleton's rig, and binds both to that fill. That is right where they are one rig as
UsdSkel maps the animation (joints by name, in any order; same hierarchy and rest pose); where
they are not, the same values are another motion on the second, which the fill never judged:
the shot is refused, one line naming both skeletons and the animation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from usd_fixtures import digest, tween

SHOT = Path(__file__).resolve().parents[2] / "examples" / "sh010_walk.usda"
ANIM = "/World/Walker/Skel/Anim"
FIRST, SECOND = "/World/Walker/Skel", "/World/Walker2/Skel"


def _second_character(shot: Path, how: str) -> None:
    """A copy of the walker's skeleton bound to the walker's animation; ``how`` it differs:
    "same", "order" (the legs listed the other way round), "rest" (a longer spine),
    "joints" (no right toes), "parent" (the left hand under the right forearm)."""
    from pxr import Sdf, Usd, UsdSkel, Vt

    layer = Sdf.Layer.FindOrOpen(str(shot))
    assert Sdf.CopySpec(layer, "/World/Walker", layer, "/World/Walker2")
    walker2 = layer.GetPrimAtPath("/World/Walker2")
    for name in [n for n in walker2.nameChildren.keys() if n != "Skel"]:  # no mesh to skin
        del walker2.nameChildren[name]
    del layer.GetPrimAtPath(SECOND).nameChildren["Anim"]
    layer.Save()
    stage = Usd.Stage.Open(layer)
    prim = stage.GetPrimAtPath(SECOND)
    UsdSkel.BindingAPI(prim).GetAnimationSourceRel().SetTargets([ANIM])
    skel = UsdSkel.Skeleton(prim)
    joints = list(skel.GetJointsAttr().Get())
    rest = list(skel.GetRestTransformsAttr().Get())
    bind = list(skel.GetBindTransformsAttr().Get())
    order = list(range(len(joints)))
    if how == "order":
        left = [i for i, t in enumerate(joints) if t.startswith("Hips/UpperLeg_L")]
        right = [i for i, t in enumerate(joints) if t.startswith("Hips/UpperLeg_R")]
        order = [i for i in order if i not in left + right] + right + left
    elif how == "joints":
        order = [i for i, t in enumerate(joints) if not t.endswith("Toes_R")]
    elif how == "rest":
        i = joints.index("Hips/Spine")
        rest[i].SetTranslateOnly(rest[i].ExtractTranslation() * 1.3)
    elif how == "parent":  # a joint's name is its path: another parent is another joint
        i = joints.index("Hips/Spine/Chest/Shoulder_L/UpperArm_L/LowerArm_L/Hand_L")
        joints[i] = "Hips/Spine/Chest/Shoulder_R/UpperArm_R/LowerArm_R/Hand_L"
        order = [j for j in order if j != i] + [i]  # after its new parent
    skel.GetJointsAttr().Set(Vt.TokenArray([joints[i] for i in order]))
    skel.GetRestTransformsAttr().Set(Vt.Matrix4dArray([rest[i] for i in order]))
    skel.GetBindTransformsAttr().Set(Vt.Matrix4dArray([bind[i] for i in order]))
    names = prim.GetAttribute("jointNames")
    if names and names.Get() is not None:
        v = list(names.Get())
        names.Set(Vt.TokenArray([v[i] for i in order]))
    layer.Save()


@pytest.mark.parametrize("how", ["same", "order"])
def test_one_rig_in_any_joint_order_shares_one_fill(tmp_path, monkeypatch, capsys, how):
    from pxr import Usd, UsdSkel

    shot = tmp_path / "sh010.usda"
    shot.write_bytes(SHOT.read_bytes())
    _second_character(shot, how)
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--model", "interp")
    assert rc == 0, err
    review = Usd.Stage.Open(str(tmp_path / "sh010.review.v001.usda"))
    cache = UsdSkel.Cache()
    queries = [cache.GetSkelQuery(UsdSkel.Skeleton(review.GetPrimAtPath(p))) for p in (FIRST, SECOND)]
    for q in queries:
        assert str(q.GetAnimQuery().GetPrim().GetPath()) == ANIM + "_tween"
    # What UsdSkel shows on each, joint by name: the same pose, between keys too.
    a, b = ([str(t) for t in q.GetJointOrder()] for q in queries)
    for t in (1001, 1005, 1050):
        la = np.array(queries[0].ComputeJointLocalTransforms(t))
        lb = np.array(queries[1].ComputeJointLocalTransforms(t))
        assert np.array_equal(la[[a.index(n) for n in b]], lb), t


@pytest.mark.parametrize("how", ["rest", "joints", "parent"])
def test_two_rigs_on_one_animation_are_one_line(tmp_path, monkeypatch, capsys, how):
    shot = tmp_path / "sh010.usda"
    shot.write_bytes(SHOT.read_bytes())
    _second_character(shot, how)
    before = digest(shot)
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--model", "interp")
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("tween: error: "), err
    for name in (str(shot), ANIM, FIRST, SECOND, "own SkelAnimation"):
        assert name in lines[0], (name, err)
    said = {"rest": "rest pose of joint 'Hips/Spine'", "joints": "Toes_R' is in", "parent": "Hand_L' is in"}
    assert said[how] in lines[0], err
    assert digest(shot) == before and sorted(p.name for p in tmp_path.iterdir()) == [shot.name]
