"""An animation listing joints its skeleton lacks (authored for a larger rig, or a joint
deleted from the skeleton): UsdSkel maps it by name and ignores those joints, and so does the
fill. The skeleton's joints are filled as if the extra ones were not there; the extra ones
keep the values the animator's animation gives them at every time the fill layer writes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from usd_fixtures import assert_kept_as_authored, digest, layer_samples, tween

SHOT = Path(__file__).resolve().parents[2] / "examples" / "sh010_walk.usda"
ANIM = "/World/Walker/Skel/Anim"
FILLED = "/World/Walker/Skel/Anim_tween"
EXTRA = "Hips/Tail"  # not a joint of the skeleton
AT = 3  # where the animation lists it
ATTRS = ("rotations", "translations", "scales")


def _add_joint(shot: Path, name: str, at: int) -> None:
    """Lists ``name`` in the animation at ``at``, with its own values at every sample (a
    translation that moves with time, so a held or interpolated value is told apart)."""
    from pxr import Usd, Vt

    stage = Usd.Stage.Open(str(shot))
    anim = stage.GetPrimAtPath(ANIM)
    joints = list(anim.GetAttribute("joints").Get())
    anim.GetAttribute("joints").Set(Vt.TokenArray(joints[:at] + [name] + joints[at:]))
    for attr_name in ATTRS:
        attr = anim.GetAttribute(attr_name)
        for t in attr.GetTimeSamples() or [None]:
            v = attr.Get() if t is None else attr.Get(t)
            extra = {
                "rotations": [0.1, 0.2, 0.3, 0.9],
                "translations": [1.5, 2.5, 0.0 if t is None else t - 1000],
                "scales": [1.0, 2.0, 1.0],
            }[attr_name]
            a = np.array(v)
            a = np.insert(a, at, np.array(extra, a.dtype), axis=0)
            new = type(v).FromNumpy(a)
            attr.Set(new) if t is None else attr.Set(new, t)
    stage.Save()


@pytest.mark.parametrize("model", ["interp", "spline"])
def test_joints_the_skeleton_lacks_are_ignored_and_kept(tmp_path, monkeypatch, capsys, model):
    from pxr import Usd

    plain, odd = tmp_path / "plain" / "sh010.usda", tmp_path / "odd" / "sh010.usda"
    for p in (plain, odd):
        p.parent.mkdir()
        p.write_bytes(SHOT.read_bytes())
    _add_joint(odd, EXTRA, AT)
    before = digest(odd)

    rc, err = tween(monkeypatch, capsys, "fill-local", plain, "--model", model)
    assert rc == 0, err
    rc, err = tween(monkeypatch, capsys, "fill-local", odd, "--model", model)
    assert rc == 0, err
    warnings = [ln for ln in err.splitlines() if "not in the skeleton" in ln]
    assert len(warnings) == 1, err
    assert warnings[0].startswith("tween: warning: ") and str(odd) in warnings[0]
    assert ANIM in warnings[0] and repr(EXTRA) in warnings[0] and " 1 of " in warnings[0]
    assert digest(odd) == before  # the animator's file is never written

    joints_p, plain_s = layer_samples(plain.parent / "sh010.tween.v001.usda", FILLED, ATTRS)
    joints_o, odd_s = layer_samples(odd.parent / "sh010.tween.v001.usda", FILLED, ATTRS)
    assert joints_o == joints_p[:AT] + [EXTRA] + joints_p[AT:]  # every joint the animator listed
    keep = [i for i in range(len(joints_o)) if i != AT]

    stage = Usd.Stage.Open(str(odd))
    src = stage.GetPrimAtPath(ANIM)
    keys = src.GetAttribute("rotations").GetTimeSamples()
    # The skeleton's joints: the fill of the shot without the extra joint; the extra joint:
    # what the animator's animation gives.
    assert_kept_as_authored(odd_s, plain_s, src, keep, [AT], keys)
    # Between keys the skeleton's joints move (filled), not held at a key.
    r = odd_s["rotations"]
    mid = (keys[0] + keys[1]) / 2
    assert not np.array_equal(r[mid][keep], r[keys[0]][keep])
    assert not np.array_equal(r[mid][keep], r[keys[1]][keep])


def test_several_takes_keep_the_extra_joint_in_each(tmp_path, monkeypatch, capsys):
    from pxr import Usd

    shot = tmp_path / "sh010.usda"
    shot.write_bytes(SHOT.read_bytes())
    _add_joint(shot, EXTRA, 0)
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--model", "interp", "--takes", "2")
    assert rc == 0, err
    stage = Usd.Stage.Open(str(tmp_path / "sh010.review.v001.usda"))
    src = stage.GetPrimAtPath(ANIM).GetAttribute("translations")
    filled = stage.GetPrimAtPath(FILLED)
    assert list(filled.GetAttribute("joints").Get())[0] == EXTRA
    vset = stage.GetPrimAtPath("/World").GetVariantSets().GetVariantSet("tweenTake")
    for take in vset.GetVariantNames():
        vset.SetVariantSelection(take)
        attr = filled.GetAttribute("translations")
        assert attr.GetTimeSamples()
        for t in attr.GetTimeSamples():
            assert np.array_equal(np.array(attr.Get(t))[0], np.array(src.Get(t))[0]), (take, t)


def test_an_animation_of_none_of_the_skeletons_joints_is_one_line(tmp_path, monkeypatch, capsys):
    from pxr import Usd, Vt

    shot = tmp_path / "sh010.usda"
    shot.write_bytes(SHOT.read_bytes())
    stage = Usd.Stage.Open(str(shot))
    attr = stage.GetPrimAtPath(ANIM).GetAttribute("joints")
    attr.Set(Vt.TokenArray([f"Other{i}" for i in range(len(attr.Get()))]))
    stage.Save()
    before = digest(shot)
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--model", "interp")
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("tween: error: "), err
    assert str(shot) in lines[0] and ANIM in lines[0] and "none of the joints" in lines[0], err
    assert digest(shot) == before and sorted(p.name for p in tmp_path.iterdir()) == [shot.name]
