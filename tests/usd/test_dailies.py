"""The dailies step: `tween approve` (a new fill layer version with the decision) and
`tween publish` (the approved take as plain, variant-free animation over the shot)."""

import datetime
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from usd_fixtures import ANIM, FILLED, bandai_shot, tree_hashes

from pipeline.fill.api import FillOptions, fill_shot
from pipeline.usd import dailies

VARIANT = "/World{tweenTake=take%d}Character/Skel/Anim_tween"
ATTRS = ("rotations", "translations", "scales")
FRAMES = [float(t) for t in range(1001, 1022)]
KEYS = [1001.0, 1011.0, 1021.0]


def _perturb_take1(path):
    """The interpolation model makes identical takes; take 1 is made visibly different (as a
    sampling model's would be) so that the tests can tell which take was flattened."""
    from pxr import Sdf, Vt

    layer = Sdf.Layer.FindOrOpen(str(path))
    rot = Sdf.Path(VARIANT % 1).AppendProperty("rotations")
    tr = Sdf.Path(VARIANT % 1).AppendProperty("translations")
    for t in layer.ListTimeSamplesForPath(rot):
        if t in KEYS:
            continue
        q = np.array(layer.QueryTimeSample(rot, t), np.float32) + np.float32(0.2)
        q /= np.linalg.norm(q, axis=-1, keepdims=True)
        layer.SetTimeSample(rot, t, Vt.QuatfArray.FromNumpy(q.astype(np.float32)))
        v = np.array(layer.QueryTimeSample(tr, t), np.float32) + np.float32(7.5)
        layer.SetTimeSample(tr, t, Vt.Vec3fArray.FromNumpy(v))
    assert layer.Save()


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    d = tmp_path_factory.mktemp("dailies")
    shot = bandai_shot(d / "walk.usda", frames=21, keys_every=10)
    res = fill_shot(str(shot), FillOptions(model="interp", takes=2))
    assert res["layer"].endswith("walk.tween.v001.usda")
    _perturb_take1(res["layer"])
    return d


@pytest.fixture
def shot(base, tmp_path, monkeypatch):
    """A fresh copy of the shot and its v001 fill (two takes), approved by 'alice'."""
    for name in ("LOGNAME", "USER", "LNAME", "USERNAME"):
        monkeypatch.setenv(name, "alice")
    d = tmp_path / "shots"
    shutil.copytree(base, d)
    return d / "walk.usda"


def tween(capsys, *args):
    from pipeline.cli import main

    with pytest.raises(SystemExit) as e:
        main([str(a) for a in args])
    out = capsys.readouterr()
    return e.value.code, out.out, out.err


def _take_samples(layer_path, take, attr):
    from pxr import Sdf

    layer = Sdf.Layer.OpenAsAnonymous(str(layer_path))
    p = Sdf.Path(VARIANT % take).AppendProperty(attr)
    return {t: np.array(layer.QueryTimeSample(p, t)) for t in layer.ListTimeSamplesForPath(p)}


def _bits(a):
    a = np.ascontiguousarray(a)
    return a.view({2: np.uint16, 4: np.uint32}[a.dtype.itemsize])


def test_approve_writes_next_version_with_decision(shot, capsys):
    from pxr import Usd

    d = shot.parent
    v1 = d / "walk.tween.v001.usda"
    before = tree_hashes(d)
    code, out, err = tween(capsys, "approve", shot, "--take", 1, "--note", "good arc on the turn")
    assert code == 0, err
    r = json.loads(out)
    v2, review = d / "walk.tween.v002.usda", d / "walk.review.v002.usda"
    assert r["layer"] == str(v2) and r["review"] == str(review) and r["version"] == 2
    assert r["of"] == str(v1) and r["take"] == 1 and r["by"] == "alice"
    # Every file that was there is byte-identical; exactly v002 and its review layer are new.
    after = tree_hashes(d)
    assert {k: after[k] for k in before} == before
    assert set(after) - set(before) == {str(v2), str(review)}
    # The decision, in the stage the new review layer composes.
    stage = Usd.Stage.Open(str(review))
    assert [os.path.basename(p) for p in stage.GetRootLayer().subLayerPaths] == [v2.name, "walk.usda"]
    world = stage.GetPrimAtPath("/World")
    assert world.HasAPI("TweenAPI")
    assert world.GetAttribute("tween:reviewStatus").Get() == "approved"
    assert world.GetAttribute("tween:approvedTake").Get() == 1
    assert world.GetAttribute("tween:approvedBy").Get() == "alice"
    assert world.GetAttribute("tween:approvalNote").Get() == "good arc on the turn"
    at = datetime.datetime.fromisoformat(world.GetAttribute("tween:approvedAt").Get())
    assert at.utcoffset() == datetime.timedelta(0)
    assert abs((datetime.datetime.now(datetime.UTC) - at).total_seconds()) < 120
    # The approved take is the one the review shows; v002 holds v001's takes unchanged.
    assert world.GetVariantSet("tweenTake").GetVariantSelection() == "take1"
    for take in (0, 1):
        for attr in ATTRS:
            a, b = _take_samples(v1, take, attr), _take_samples(v2, take, attr)
            assert sorted(a) == sorted(b) == FRAMES
            assert all(np.array_equal(_bits(a[t]), _bits(b[t])) for t in FRAMES)
    shown = stage.GetPrimAtPath(FILLED).GetAttribute("translations")
    take1 = _take_samples(v1, 1, "translations")
    assert all(np.array_equal(np.array(shown.Get(t)), take1[t]) for t in FRAMES)
    from pxr import Sdf

    info = dict(Sdf.Layer.OpenAsAnonymous(str(v2)).customLayerData["tween"])
    assert info["version"] == 2 and info["review"] == review.name and info["takes"] == 2
    assert dict(info["approval"])["of"] == v1.name
    # decision(): the fill layer, the approval layer and either review layer all report it.
    for p in (v1, v2, review, d / "walk.review.v001.usda"):
        got = dailies.decision(p)
        assert got["status"] == "approved" and got["take"] == 1 and got["by"] == "alice", p
        assert got["note"] == "good arc on the turn" and got["layer"] == str(v2)
    assert dailies.decision(shot) is None and dailies.decision(d / "nothing.usda") is None


def test_decision_pending_is_none(shot):
    assert dailies.decision(shot.parent / "walk.tween.v001.usda") is None
    assert dailies.decision(shot.parent / "walk.review.v001.usda") is None


def _garbage_latest(shot):
    (shot.parent / "walk.tween.v002.usda").write_text("#usda 1.0\nthis is not usd {\n")


def _approved(shot):
    dailies.approve(str(shot), 0)


def _no_fill(shot):
    for p in shot.parent.glob("walk.*v001*"):
        p.unlink()


REFUSALS = [
    # (name, prepare, args, the file named, words in the line)
    ("no-fill", _no_fill, ["approve", "{shot}", "--take", "0"], "{shot}", "no fill yet"),
    ("unknown-take", None, ["approve", "{shot}", "--take", "2"], "{d}/walk.tween.v001.usda",
     "take 2 is not one of the layer's takes (0, 1)"),
    ("second-approval", _approved, ["approve", "{shot}", "--take", "1"], "{d}/walk.tween.v002.usda",
     "already approved (take 0 by alice at "),
    ("unreadable", _garbage_latest, ["approve", "{shot}", "--take", "0"], "{d}/walk.tween.v002.usda",
     "cannot read the fill layer"),
    ("missing-shot", None, ["approve", "{d}/nope.usda", "--take", "0"], "{d}/nope.usda", "file not found"),
    ("publish-pending", None, ["publish", "{shot}"], "{d}/walk.tween.v001.usda", "nothing approved"),
    ("publish-no-fill", _no_fill, ["publish", "{shot}"], "{shot}", "no fill yet"),
    ("publish-format", _approved, ["publish", "{shot}", "--format", "fbx"], "--format 'fbx'", "usda or usdc"),
    ("publish-empty-out", _approved, ["publish", "{shot}", "--out", ""], "--out ''", "empty; give the published layer's path"),
    ("publish-unreadable", _garbage_latest, ["publish", "{shot}"], "{d}/walk.tween.v002.usda",
     "cannot read the fill layer"),
    # A layer usd-tween made, given as the shot: its review layer would stack the next version
    # over the fill (or over a review) without the shot, where nothing composes.
    ("approve-fill-layer", None, ["approve", "{d}/walk.tween.v001.usda", "--take", "1"],
     "{d}/walk.tween.v001.usda", "is a fill layer, not a shot: give the shot it was made from (walk.usd*)"),
    ("approve-review-layer", None, ["approve", "{d}/walk.review.v001.usda", "--take", "1"],
     "{d}/walk.review.v001.usda", "is a review layer, not a shot"),
    ("publish-fill-layer", _approved, ["publish", "{d}/walk.tween.v002.usda"], "{d}/walk.tween.v002.usda",
     "is a fill layer, not a shot"),
    ("fill-review-layer", None, ["fill-local", "{d}/walk.review.v001.usda"], "{d}/walk.review.v001.usda",
     "is a review layer, not a shot"),
]  # fmt: skip


@pytest.mark.parametrize("name,prepare,args,where,words", REFUSALS, ids=[r[0] for r in REFUSALS])
def test_refusals_are_one_line_and_write_nothing(shot, capsys, name, prepare, args, where, words):
    d = shot.parent
    if prepare:
        prepare(shot)
    capsys.readouterr()
    before = tree_hashes(d)
    code, out, err = tween(capsys, *[a.format(shot=shot, d=d) for a in args])
    assert code == 2 and out == ""
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"tween: error: {where.format(shot=shot, d=d)}: "), err
    assert words in lines[0], err
    assert tree_hashes(d) == before  # nothing written, no lock or temp file left


def test_second_approval_names_take_and_reviewer(shot):
    from pipeline.errors import TweenError

    dailies.approve(str(shot), 1, note="ok")
    with pytest.raises(
        TweenError, match=r"walk\.tween\.v002\.usda: already approved \(take 1 by alice at .*a new"
    ):
        dailies.approve(str(shot), 0)
    assert not (shot.parent / "walk.tween.v003.usda").exists()


def _composed(published, shot):
    """A fresh stage: the published layer as a stronger sublayer over the shot."""
    from pxr import Sdf, Usd

    root = Sdf.Layer.CreateAnonymous(".usda")
    root.timeCodesPerSecond = 30  # the shot's rate: else USD scales the sublayers' times
    root.subLayerPaths = [str(published), str(shot)]
    return Usd.Stage.Open(root)


def _check_published(published, shot, take_of):
    """The approved take's samples, bit for bit, on the shot's own Anim at every frame."""
    from pxr import Sdf, Usd, UsdSkel

    layer = Sdf.Layer.OpenAsAnonymous(str(published))
    # Plain animation: no variant sets, no variant specs, nothing but overs.
    specs = []
    layer.Traverse(Sdf.Path.absoluteRootPath, specs.append)
    assert specs and not any(p.ContainsPrimVariantSelection() for p in specs)
    for p in specs:
        if p.IsPrimPath():
            spec = layer.GetPrimAtPath(p)
            assert spec.specifier == Sdf.SpecifierOver and not spec.variantSets
            assert not len(spec.variantSelections) and not spec.HasInfo("variantSetNames")
    assert layer.GetPrimAtPath(FILLED) is None and layer.GetPrimAtPath(ANIM) is not None
    stage = _composed(published, shot)
    assert not any(p.GetVariantSets().GetNames() for p in Usd.PrimRange.Stage(stage))
    assert not stage.GetPrimAtPath(FILLED)
    anim = stage.GetPrimAtPath(ANIM)
    assert anim.GetTypeName() == "SkelAnimation"
    for attr in ATTRS:
        want = _take_samples(take_of, 1, attr)
        a = anim.GetAttribute(attr)
        assert a.GetTimeSamples() == FRAMES
        for t in FRAMES:
            assert np.array_equal(_bits(np.array(a.Get(t))), _bits(want[t])), (attr, t)
    # Keys marked, and they are the animator's values.
    assert list(anim.GetAttribute("tween:keyTimes").Get()) == KEYS
    shot_stage = Usd.Stage.Open(str(shot))
    orig = shot_stage.GetPrimAtPath(ANIM).GetAttribute("rotations")
    for t in KEYS:
        assert np.array_equal(np.array(anim.GetAttribute("rotations").Get(t)), np.array(orig.Get(t)))
    # UsdSkel poses the skeleton from the original animation prim.
    skel = UsdSkel.Skeleton(stage.GetPrimAtPath("/World/Character/Skel"))
    cache = UsdSkel.Cache()
    cache.Populate(UsdSkel.Root(stage.GetPrimAtPath("/World/Character")), Usd.PrimDefaultPredicate)
    q = cache.GetSkelQuery(skel)
    assert q.GetAnimQuery().GetPrim().GetPath() == ANIM
    assert len(q.ComputeJointLocalTransforms(1005.0)) == len(anim.GetAttribute("joints").Get())
    return layer


def test_publish_flattens_the_approved_take_onto_the_original_anim(shot, capsys):
    d = shot.parent
    v1 = d / "walk.tween.v001.usda"
    assert tween(capsys, "approve", shot, "--take", 1, "--note", "ship it")[0] == 0
    before = tree_hashes(d)
    code, out, err = tween(capsys, "publish", shot)
    assert code == 0, err
    published = d / "walk.publish.v002.usda"
    assert out.strip() == str(published)
    after = tree_hashes(d)
    assert {k: after[k] for k in before} == before and set(after) - set(before) == {str(published)}
    layer = _check_published(published, shot, v1)
    assert "variant" not in published.read_text()
    # Take 1 really differs from take 0 where it was not keyed.
    t0, t1 = _take_samples(v1, 0, "translations"), _take_samples(v1, 1, "translations")
    assert not np.array_equal(t0[1005.0], t1[1005.0])
    info = dict(layer.customLayerData["tween"])
    assert info["kind"] == "publish" and info["take"] == 1 and info["fillLayer"] == "walk.tween.v002.usda"
    assert info["model"] == "interpolation" and info["modelHash"] == "none"
    appr = dict(info["approval"])
    assert appr["by"] == "alice" and appr["take"] == 1 and appr["note"] == "ship it"
    assert layer.timeCodesPerSecond == 30 and layer.startTimeCode == 1001 and layer.endTimeCode == 1021
    assert dailies.decision(published)["take"] == 1
    # Never overwritten: a second publish of the same approval is refused.
    code, _, err = tween(capsys, "publish", shot)
    assert code == 2 and "already exists" in err and len(err.splitlines()) == 1
    assert tree_hashes(d) == after


def test_published_layer_opens_without_this_package(shot):
    # As in usdview or Blender: no usd-tween import, no TweenAPI plugin.
    dailies.approve(str(shot), 1)
    published = dailies.publish(str(shot))["layer"]
    code = (
        "import sys; from pxr import Sdf, Usd\n"
        "r = Sdf.Layer.CreateAnonymous('.usda'); r.timeCodesPerSecond = 30; r.subLayerPaths = sys.argv[1:3]\n"
        "s = Usd.Stage.Open(r); a = s.GetPrimAtPath(sys.argv[3])\n"
        "print(len(a.GetAttribute('translations').GetTimeSamples()), a.GetAttribute('translations').Get(1005)[0])"
    )
    env = {k: v for k, v in os.environ.items() if k != "PXR_PLUGINPATH_NAME"}
    res = subprocess.run([sys.executable, "-c", code, published, str(shot), ANIM], env=env,
                         capture_output=True, text=True, check=True)  # fmt: skip
    n, first = res.stdout.split(" ", 1)
    want = _take_samples(shot.parent / "walk.tween.v001.usda", 1, "translations")[1005.0][0]
    assert int(n) == 21 and np.allclose([float(x) for x in first.strip("()\n").split(",")], want, atol=1e-4)


def test_publish_usdc_and_out_path(shot, capsys, tmp_path):
    d = shot.parent
    dailies.approve(str(shot), 1)
    code, out, err = tween(capsys, "publish", shot, "--format", "usdc")
    assert code == 0, err
    published = d / "walk.publish.v002.usdc"
    assert out.strip() == str(published) and published.read_bytes()[:8] == b"PXR-USDC"
    _check_published(published, shot, d / "walk.tween.v001.usda")
    # --out: any file name; its extension decides the format.
    dest = tmp_path / "pub" / "walk_anim.usda"
    dest.parent.mkdir()
    code, out, err = tween(capsys, "publish", shot, "--out", dest)
    assert code == 0 and out.strip() == str(dest), err
    _check_published(dest, shot, d / "walk.tween.v001.usda")
    code, _, err = tween(capsys, "publish", shot, "--out", dest.with_suffix(".usdc"), "--format", "usda")
    assert code == 2 and "does not match" in err and not dest.with_suffix(".usdc").exists()


def test_publish_out_under_a_file_or_a_read_only_folder_says_which(shot, capsys, tmp_path):
    """A --out under a file said its folder "does not exist"; one in a read-only folder
    ended "(use --out PATH)" though --out was given."""
    dailies.approve(str(shot), 1)
    (tmp_path / "afile").write_text("")
    code, out, err = tween(capsys, "publish", shot, "--out", tmp_path / "afile" / "x.usda")
    assert code == 2 and out == "" and f"the folder {tmp_path / 'afile'} is not a folder" in err
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        code, out, err = tween(capsys, "publish", shot, "--out", ro / "x.usda")  # by its mode, even for root
        assert code == 2 and "read-only (use another --out)" in err, err
        assert list(ro.iterdir()) == []
    finally:
        ro.chmod(0o755)


def test_single_take_fill_approve_and_publish(tmp_path, monkeypatch):
    monkeypatch.setenv("LOGNAME", "bob")
    shot = bandai_shot(tmp_path / "run.usda", frames=21, keys_every=10)
    shot_bytes = shot.read_bytes()
    res = fill_shot(str(shot), FillOptions(model="interp", takes=1, fmt="usdc"))
    from pipeline.errors import TweenError

    with pytest.raises(TweenError, match="take 1 is not one of the layer's takes \\(0\\)"):
        dailies.approve(str(shot), 1)
    r = dailies.approve(str(shot), 0)
    assert r["layer"].endswith("run.tween.v002.usdc") and r["by"] == "bob"
    pub = dailies.publish(str(shot))
    assert pub["layer"].endswith("run.publish.v002.usda") and pub["take"] == 0
    stage = _composed(pub["layer"], shot)
    from pxr import Sdf

    fill = Sdf.Layer.OpenAsAnonymous(res["layer"])
    rot = Sdf.Path(FILLED).AppendProperty("rotations")
    a = stage.GetPrimAtPath(ANIM).GetAttribute("rotations")
    assert a.GetTimeSamples() == FRAMES
    for t in FRAMES:
        assert np.array_equal(np.array(a.Get(t)), np.array(fill.QueryTimeSample(rot, t)))
    assert shot.read_bytes() == shot_bytes


def test_status_line_shows_the_decision(shot, capsys, monkeypatch):
    from workers import jobs

    v1 = shot.parent / "walk.tween.v001.usda"
    state = jobs.JobState(id="J1", shot=str(shot), state="SUCCESS", result={"layer": str(v1)})
    monkeypatch.setattr(jobs, "state", lambda j: state)
    monkeypatch.delenv("TWEEN_BROKER_URL", raising=False)
    code, out, _ = tween(capsys, "status", "J1")
    assert code == 0 and out.strip() == f"J1 {shot}: success, layer {v1}"
    dailies.approve(str(shot), 1, note="nice\nweight shift")
    code, out, _ = tween(capsys, "status", "J1")
    assert code == 0 and len(out.splitlines()) == 1
    line = out.strip()
    assert line.startswith(f"J1 {shot}: success, layer {v1}, approved take 1 by alice at ")
    assert line.endswith(f'("nice weight shift") in {shot.parent / "walk.tween.v002.usda"}')


def test_approve_publish_and_review_refuse_another_shots_fills(tmp_path, capsys):
    """sh010.v2.usda, never filled, beside sh010.v1.usda's fills (one series, ``sh010``):
    approve wrote v1's fill as v2's version and publish published it, exit 0."""
    v1 = bandai_shot(tmp_path / "sh010.v1.usda", frames=21, keys_every=10)
    v2 = tmp_path / "sh010.v2.usda"
    shutil.copy(v1, v2)
    fill_shot(str(v1), FillOptions(model="interp"))
    capsys.readouterr()  # the fill's own lines
    before = tree_hashes(tmp_path)
    for args in (("approve", v2, "--take", "0"), ("publish", v2), ("review", v2, "--size", "160x90")):
        code, out, err = tween(capsys, *args)
        assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, (args, err)
        assert "which hold the fills of sh010.v1.usda" in err, err
    assert tree_hashes(tmp_path) == before


def test_a_shot_named_with_glob_characters_finds_its_versions(tmp_path, capsys):
    """``sh[0].usda``: its versions were looked up by an unescaped glob pattern, so the second
    fill found no v001 (and refused its review layer) and approve said "no fill yet"."""
    shot = bandai_shot(tmp_path / "sh[0].usda", frames=21, keys_every=10)
    for n in (1, 2):
        assert fill_shot(str(shot), FillOptions(model="interp"))["version"] == n
    code, out, err = tween(capsys, "approve", shot, "--take", "0")
    assert code == 0, err
    assert (tmp_path / "sh[0].tween.v003.usda").is_file()
    code, out, err = tween(capsys, "publish", shot)
    assert code == 0 and out.strip() == str(tmp_path / "sh[0].publish.v003.usda"), err


def test_approve_and_publish_refuse_a_latest_fill_deleted_by_hand(tmp_path, capsys):
    """v002's fill layer deleted by hand, its review layer left: approve took v001 for the
    latest fill and wrote its approval as v003, publish published v001, exit 0."""
    shot = bandai_shot(tmp_path / "sh020.usda", frames=21, keys_every=10)
    for n in (1, 2):
        assert fill_shot(str(shot), FillOptions(model="interp"))["version"] == n
    (tmp_path / "sh020.tween.v002.usda").unlink()
    capsys.readouterr()  # the fills' own lines
    before = tree_hashes(tmp_path)
    for args in (("approve", shot, "--take", "0"), ("publish", shot)):
        code, out, err = tween(capsys, *args)
        assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, (args, err)
        assert err.startswith(f"tween: error: {tmp_path / 'sh020.tween.v002.usda'}: the latest fill of"), err
        assert "sh020.review.v002.usda is); run tween fill again" in err, err
    assert tree_hashes(tmp_path) == before
    assert fill_shot(str(shot), FillOptions(model="interp"))["version"] == 3  # a new fill mends it
    code, out, err = tween(capsys, "approve", shot, "--take", "0")
    assert code == 0, err
