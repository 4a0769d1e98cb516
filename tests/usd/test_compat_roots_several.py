"""A skeleton of several root joints (a Blender armature's unparented IK targets and poles, a
Maya rig's prop or helper root): UsdSkel allows them. The hierarchy under the root holding the
most joints is the character and is filled; the joints under the other roots are kept as the
joints the skeleton lacks are: at every time the fill layer writes, the value the animator's
animation gives there. Two largest hierarchies of one size are refused (neither is the
character). Before, any second root was refused ("skeleton topology: 2 root joints")."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from usd_fixtures import assert_kept_as_authored, digest, layer_samples, tween

SHOT = Path(__file__).resolve().parents[2] / "examples" / "sh010_walk.usda"
SKEL = "/World/Walker/Skel"
ANIM = f"{SKEL}/Anim"
FILLED = f"{SKEL}/Anim_tween"
SECOND = ["IK_Foot_L", "IK_Foot_L/Pole_L"]  # an unparented IK target and its pole
AT = 2  # where the animation lists them
ATTRS = ("rotations", "translations", "scales")


def _second_root(shot: Path, names=SECOND, at: int = AT, animated: bool = True) -> None:
    """Lists the joints ``names`` (a hierarchy of their own) FIRST in the skeleton, so that
    every joint of the character moves in its arrays, and, ``animated``, in the animation at
    ``at`` with keyed values of their own that move with time (a held or interpolated value
    is told apart)."""
    from pxr import Gf, Usd, Vt

    stage = Usd.Stage.Open(str(shot))
    skel = stage.GetPrimAtPath(SKEL)
    joints = skel.GetAttribute("joints")
    joints.Set(Vt.TokenArray(list(names) + list(joints.Get())))
    for n in ("restTransforms", "bindTransforms"):
        a = skel.GetAttribute(n)
        mats = [Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(10 + i, 5, 3)) for i in range(len(names))]
        a.Set(Vt.Matrix4dArray(mats + list(a.Get())))
    if animated:
        anim = stage.GetPrimAtPath(ANIM)
        listed = list(anim.GetAttribute("joints").Get())
        anim.GetAttribute("joints").Set(Vt.TokenArray(listed[:at] + list(names) + listed[at:]))
        for name in ATTRS:
            attr = anim.GetAttribute(name)
            for t in attr.GetTimeSamples() or [None]:
                v = attr.Get() if t is None else attr.Get(t)
                k = 0.0 if t is None else t - 1000
                rows = []
                for i in range(len(names)):
                    q = np.array([0.05 * k, 0.2, 0.3 + i, 0.9])
                    rows.append(
                        {"rotations": q / np.linalg.norm(q), "translations": [1.5 + i, 2.5, k * (i + 1)],
                         "scales": [1.0, 1.0 + i, 1.0]}[name]
                    )  # fmt: skip
                a = np.insert(np.array(v), at, np.array(rows, np.array(v).dtype), axis=0)
                new = type(v).FromNumpy(a)
                attr.Set(new) if t is None else attr.Set(new, t)
    stage.Save()


def _copy(folder: Path) -> Path:
    folder.mkdir(parents=True)
    shot = folder / "sh010.usda"
    shot.write_bytes(SHOT.read_bytes())
    return shot


def _one_warning(err: str, shot: Path) -> None:
    lines = [ln for ln in err.splitlines() if "root joints" in ln]
    assert len(lines) == 1, err
    w = lines[0]
    assert w.startswith(f"tween: warning: {shot} {SKEL}: 2 root joints ('IK_Foot_L', 'Hips')"), err
    assert "the character is the hierarchy under 'Hips' (21 joints)" in w, err
    assert "the 2 joints under the other roots (the first is 'IK_Foot_L') are not filled" in w, err
    assert "error" not in err and "Traceback" not in err, err


@pytest.mark.parametrize("model", ["interp", "spline"])
def test_the_largest_hierarchy_is_filled_and_the_other_root_kept(tmp_path, monkeypatch, capsys, model):
    from pxr import Usd

    plain, odd = _copy(tmp_path / "plain"), _copy(tmp_path / "odd")
    _second_root(odd)
    before = digest(odd)
    rc, err = tween(monkeypatch, capsys, "fill-local", plain, "--model", model)
    assert rc == 0, err
    rc, err = tween(monkeypatch, capsys, "fill-local", odd, "--model", model)
    assert rc == 0, err
    _one_warning(err, odd)
    assert digest(odd) == before  # the animator's file is never written

    joints_p, plain_s = layer_samples(plain.parent / "sh010.tween.v001.usda", FILLED, ATTRS)
    joints_o, odd_s = layer_samples(odd.parent / "sh010.tween.v001.usda", FILLED, ATTRS)
    assert joints_o == joints_p[:AT] + SECOND + joints_p[AT:]  # every joint the animator listed
    other = [AT, AT + 1]
    keep = [i for i in range(len(joints_o)) if i not in other]
    stage = Usd.Stage.Open(str(odd))  # held: its prims expire with it
    src = stage.GetPrimAtPath(ANIM)
    keys = src.GetAttribute("rotations").GetTimeSamples()
    # The character: the fill of the same shot without the second root; the other root: what
    # the animator's animation gives.
    assert_kept_as_authored(odd_s, plain_s, src, keep, other, keys)
    # Between keys the character moves (filled), and so does the other root (as USD interpolates).
    r, tr = odd_s["rotations"], odd_s["translations"]
    mid = (keys[0] + keys[1]) / 2
    assert not np.array_equal(r[mid][keep], r[keys[0]][keep])
    assert not np.array_equal(r[mid][keep], r[keys[1]][keep])
    assert tr[keys[0]][AT][2] < tr[mid][AT][2] < tr[keys[1]][AT][2]


def test_several_takes_of_the_default_model_keep_the_other_root(tmp_path, monkeypatch, capsys):
    from pxr import Usd

    shot = _copy(tmp_path / "shot")
    _second_root(shot, at=0)
    before = digest(shot)
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--takes", "2")
    assert rc == 0, err
    _one_warning(err, shot)
    assert digest(shot) == before
    stage = Usd.Stage.Open(str(shot.parent / "sh010.review.v001.usda"))
    src = stage.GetPrimAtPath(ANIM)
    keys = src.GetAttribute("rotations").GetTimeSamples()
    filled = stage.GetPrimAtPath(FILLED)
    assert list(filled.GetAttribute("joints").Get()) == list(src.GetAttribute("joints").Get())
    vset = stage.GetPrimAtPath("/World").GetVariantSets().GetVariantSet("tweenTake")
    assert len(vset.GetVariantNames()) == 2
    for take in vset.GetVariantNames():
        vset.SetVariantSelection(take)
        for name in ATTRS:
            attr, orig = filled.GetAttribute(name), src.GetAttribute(name)
            times = attr.GetTimeSamples()
            assert len(times) > len(keys)
            for t in times:
                v, o = np.array(attr.Get(t)), np.array(orig.Get(t))
                assert np.array_equal(v[:2], o[:2]), (take, name, t)
                if t in keys:
                    assert np.array_equal(v, o), (take, name, t)
        r = filled.GetAttribute("rotations")
        mid = (keys[0] + keys[1]) / 2
        assert not np.array_equal(np.array(r.Get(mid))[2:], np.array(r.Get(keys[0]))[2:]), take


def test_two_hierarchies_of_one_size_are_refused_in_one_line(tmp_path, monkeypatch, capsys):
    from pxr import Usd

    shot = _copy(tmp_path / "shot")
    stage = Usd.Stage.Open(str(shot))
    hips = [str(t) for t in stage.GetPrimAtPath(SKEL).GetAttribute("joints").Get()]
    del stage
    twin = ["Twin" + t[len("Hips") :] for t in hips]  # a second rig of as many joints
    _second_root(shot, names=twin, animated=False)
    before = digest(shot)
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--model", "interp")
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(
        f"tween: error: {shot} {SKEL}: skeleton topology: 2 root joints ('Twin', 'Hips')"
    )
    assert "'Twin' and 'Hips' each hold 21 joints" in lines[0], err
    assert digest(shot) == before and sorted(p.name for p in shot.parent.iterdir()) == [shot.name]


def test_a_mapping_naming_a_joint_under_the_other_root_is_one_line(tmp_path, monkeypatch, capsys):
    shot = _copy(tmp_path / "shot")
    _second_root(shot)
    mapping = tmp_path / "map.json"
    mapping.write_text(json.dumps({"Foot_L": "IK_Foot_L/Pole_L"}))
    before = digest(shot)
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--mapping", mapping)
    assert rc == 2, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("tween: error: ")]
    assert len(errors) == 1 and errors[0] == lines[-1], err
    assert all(ln.startswith("tween: ") for ln in lines) and "Traceback" not in err, err
    assert str(shot) in errors[0] and SKEL in errors[0], err
    assert "mapping override Foot_L -> 'IK_Foot_L/Pole_L'" in errors[0], err
    # Named as what it is: a joint of the skeleton, under another root than the character's.
    assert "a joint under another root joint than the character's 'Hips'" in errors[0], err
    assert digest(shot) == before and sorted(p.name for p in shot.parent.iterdir()) == [shot.name]


def test_review_approve_and_publish_a_fill_of_several_roots(tmp_path, monkeypatch, capsys):
    from pxr import Usd

    shot = _copy(tmp_path / "shot")
    _second_root(shot)
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--model", "interp", "--takes", "2")
    assert rc == 0, err
    review = shot.parent / "sh010.review.v001.usda"
    out = tmp_path / "media"
    rc, err = tween(
        monkeypatch,
        capsys,
        "review",
        review,
        "--all-takes",
        "--size",
        "160x90",
        "--frames",
        "1001:1003",
        "-o",
        out,
    )
    assert rc == 0, err
    frames = sorted(p.name for p in out.glob("sh010_v001_take*.100*.png"))
    assert len(frames) == 6 and len(list(out.glob("*.mp4"))) == 2, sorted(p.name for p in out.iterdir())
    rc, err = tween(monkeypatch, capsys, "approve", shot, "--take", "1", "--by", "me")
    assert rc == 0, err
    rc, err = tween(monkeypatch, capsys, "publish", shot)
    assert rc == 0, err
    published = shot.parent / "sh010.publish.v002.usda"
    joints, values = layer_samples(published, ANIM, ATTRS)  # a plain animation over the animator's
    stage = Usd.Stage.Open(str(shot))
    src = stage.GetPrimAtPath(ANIM)
    assert joints == list(src.GetAttribute("joints").Get())
    for name in ATTRS:
        attr = src.GetAttribute(name)
        assert len(values[name]) > len(attr.GetTimeSamples())
        for t, v in values[name].items():
            assert np.array_equal(v[AT : AT + 2], np.array(attr.Get(t))[AT : AT + 2]), (name, t)


def _refused(monkeypatch, capsys, shot: Path, *reason: str) -> None:
    before = digest(shot)
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--model", "interp")
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"tween: error: {shot} "), err
    for r in reason:
        assert r in lines[0], err
    assert digest(shot) == before and sorted(p.name for p in shot.parent.iterdir()) == [shot.name]


def test_a_second_root_that_is_a_renamed_joint_of_the_character_is_refused(tmp_path, monkeypatch, capsys):
    """'Hips/UpperLeg_L' renamed 'Thigh': its children hang under Hips across the gap, and the
    thigh would pass for a second root, left unfilled while the leg below it is filled."""
    shot = _copy(tmp_path / "shot")
    shot.write_text(shot.read_text().replace('"Hips/UpperLeg_L"', '"Thigh"'))
    _refused(
        monkeypatch, capsys, shot, f"{SKEL}: skeleton topology: 2 root joints ('Hips', 'Thigh'); joint "
        "'Hips/UpperLeg_L/LowerLeg_L' is under 'Hips/UpperLeg_L', which the skeleton does not list",
    )  # fmt: skip


def test_an_animation_of_the_other_root_alone_is_refused(tmp_path, monkeypatch, capsys):
    from pxr import Usd, Vt

    shot = _copy(tmp_path / "shot")
    _second_root(shot, at=0)
    stage = Usd.Stage.Open(str(shot))
    anim = stage.GetPrimAtPath(ANIM)
    anim.GetAttribute("joints").Set(Vt.TokenArray(SECOND))
    for name in ATTRS:
        attr = anim.GetAttribute(name)
        for t in attr.GetTimeSamples():
            v = attr.Get(t)
            attr.Set(type(v).FromNumpy(np.array(v)[:2]), t)
    stage.Save()
    del stage
    _refused(
        monkeypatch, capsys, shot, f"{ANIM}: animation lists none of the joints of the hierarchy under 'Hips' "
        f"(the character) of its skeleton {SKEL} (its first is 'IK_Foot_L')",
    )  # fmt: skip


@pytest.mark.parametrize("cleared", ["translations", "rotations"])
def test_an_attribute_the_animation_never_authors_keeps_the_other_roots_at_rest(
    tmp_path, monkeypatch, capsys, cleared
):
    """No ``translations`` (or ``rotations``) authored at all: the fill reads the character's
    missing values as its rest pose, and writes the attribute for every joint, but gave the
    other roots' joints identity values (an IK target jumped to its root's origin in the
    review). They keep the skeleton's rest values for it now, and their authored ones for the
    other attributes."""
    from pxr import Usd, UsdSkel

    shot = _copy(tmp_path / "shot")
    _second_root(shot)
    stage = Usd.Stage.Open(str(shot))
    anim = stage.GetPrimAtPath(ANIM)
    joints = [str(j) for j in anim.GetAttribute("joints").Get()]
    anim.GetAttribute(cleared).Clear()
    stage.Save()
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--model", "spline")
    assert rc == 0, err

    query = UsdSkel.Cache().GetSkelQuery(UsdSkel.Skeleton(stage.GetPrimAtPath(SKEL)))
    trans, rots, _ = UsdSkel.DecomposeTransforms(
        query.ComputeJointLocalTransforms(Usd.TimeCode.Default(), True)
    )
    order = [str(j) for j in query.GetJointOrder()]
    rest = {"translations": np.array(trans), "rotations": np.array(rots)}
    kept = "rotations" if cleared == "translations" else "translations"
    _, written = layer_samples(shot.parent / "sh010.tween.v001.usda", FILLED, ATTRS)
    src = anim.GetAttribute(kept)
    for t in (1005.0, 1011.0):
        for j in SECOND:
            a = joints.index(j)
            np.testing.assert_allclose(written[cleared][t][a], rest[cleared][order.index(j)], atol=1e-6)
            np.testing.assert_array_equal(written[kept][t][a], np.array(src.Get(t))[a])


def test_a_refusal_after_the_shot_is_read_is_its_one_line(tmp_path, monkeypatch, capsys):
    """The reader said its warning (several roots) as it read the shot, so a refusal by the
    fill's plan after it (no keys at all) came second, after that warning: two lines. The
    warnings now wait with the plan's notes until every check has passed."""
    from pxr import Usd

    shot = _copy(tmp_path / "shot")
    _second_root(shot)
    stage = Usd.Stage.Open(str(shot))
    for name in ("rotations", "translations"):  # one value each, no samples: no keys
        attr = stage.GetPrimAtPath(ANIM).GetAttribute(name)
        first = attr.Get(attr.GetTimeSamples()[0])
        attr.Clear()
        attr.Set(first)
    stage.Save()
    before = digest(shot)
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--model", "interp")
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 1 and lines[0].startswith(f"tween: error: {shot} {ANIM}"), err
    assert "key" in lines[0] and digest(shot) == before, err
