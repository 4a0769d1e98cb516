"""Odd and hostile inputs found by generating them (a fuzzing session): each is one line on
stderr naming the file or option, exit 2, nothing written, the input untouched."""

from __future__ import annotations

import gzip
import os
import sys
from pathlib import Path

import numpy as np
import pytest
from usd_fixtures import ANIM, BANDAI_CLIP, tree_hashes, tween

from pipeline.cli import main
from pipeline.errors import MotionFormatError
from pipeline.motion import bvh

SHOT = Path(__file__).resolve().parents[2] / "examples" / "sh010_walk.usda"


def _one_error(rc: int, err: str, *names: str) -> None:
    """Exit 2, one error line (the last; progress lines before it are the fill's own), no traceback."""
    assert rc == 2, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert all(ln.startswith("tween: ") for ln in lines), err
    errors = [ln for ln in lines if ln.startswith("tween: error: ")]
    assert len(errors) == 1 and errors[0] == lines[-1], err
    for n in names:
        assert n in errors[0], (n, err)


@pytest.fixture
def shot(tmp_path):
    out = tmp_path / "sh010.usda"
    out.write_bytes(SHOT.read_bytes())
    return out


def _anim_path(shot: Path) -> str:
    from pxr import Usd, UsdSkel

    stage = Usd.Stage.Open(str(shot))
    return next(str(p.GetPath()) for p in stage.Traverse() if p.IsA(UsdSkel.Animation))


def test_a_shot_path_that_is_not_utf8_is_one_line(shot, monkeypatch, capsys):
    if sys.platform == "darwin":  # APFS refuses such names itself
        pytest.skip("the file system refuses non-UTF-8 names")
    odd = Path(os.fsdecode(bytes(shot.parent) + b"/sh\xffot.usda"))
    odd.write_bytes(shot.read_bytes())
    rc, err = tween(monkeypatch, capsys, "fill-local", odd, "--out-dir", shot.parent / "out")
    _one_error(rc, err, "not UTF-8")
    assert not (shot.parent / "out").exists()
    rc, err = tween(monkeypatch, capsys, "convert", BANDAI_CLIP, shot.parent / "o\udcff.usda")
    _one_error(rc, err, "not UTF-8")


def test_bytes_that_are_not_utf8_inside_a_usda_are_one_line(shot, monkeypatch, capsys):
    text = shot.read_bytes()
    name = _anim_path(shot).rsplit("/", 1)[-1].encode()
    shot.write_bytes(text.replace(b'"' + name + b'"', b'"' + name[:2] + b"\xff\xfe" + name[2:] + b'"', 1))
    before = shot.read_bytes()
    rc, err = tween(monkeypatch, capsys, "fill-local", shot)
    _one_error(rc, err, str(shot), "not UTF-8")
    assert shot.read_bytes() == before and sorted(p.name for p in shot.parent.iterdir()) == [shot.name]


@pytest.mark.parametrize("how", ["string[]", "time-sampled"])
def test_key_times_of_the_wrong_kind_are_one_line_naming_them(shot, how, monkeypatch, capsys):
    from pxr import Sdf, Usd, Vt

    stage = Usd.Stage.Open(str(shot))
    anim = stage.GetPrimAtPath(_anim_path(shot))
    if how == "string[]":
        anim.CreateAttribute("tween:keyTimes", Sdf.ValueTypeNames.StringArray).Set(Vt.StringArray(["a", "b"]))
    else:
        anim.CreateAttribute("tween:keyTimes", Sdf.ValueTypeNames.DoubleArray).Set(
            Vt.DoubleArray([1001.0]), 1001
        )
    stage.Save()
    rc, err = tween(monkeypatch, capsys, "fill-local", shot)
    _one_error(rc, err, str(shot), "tween:keyTimes", how)


@pytest.mark.parametrize("kind", ["text", "garbage.usda", "usdz", "missing"])
def test_a_review_layer_that_is_no_usd_layer_is_one_line(shot, kind, monkeypatch, capsys):
    """Refused before the model runs: it was found only when the layers were written, after
    the fill's own lines (the model, the trust decision) were said."""
    review = (
        shot.parent / {"text": "r.txt", "garbage.usda": "g.usda", "usdz": "r.usdz", "missing": "m.usda"}[kind]
    )
    if kind != "missing":
        review.write_bytes(os.urandom(512) if kind != "text" else b"hello\n")
    before = sorted(p.name for p in shot.parent.iterdir())
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--review-layer", review)
    _one_error(rc, err, str(review))
    assert len(err.strip().splitlines()) == 1, err  # nothing of the fill said before it
    assert sorted(p.name for p in shot.parent.iterdir()) == before  # no fill layer left


def test_convert_never_writes_over_its_input(tmp_path, monkeypatch, capsys):
    clip = tmp_path / "clip.usda"  # a BVH named like a shot
    clip.write_bytes(gzip.decompress(BANDAI_CLIP.read_bytes()))
    before = clip.read_bytes()
    rc, err = tween(monkeypatch, capsys, "convert", clip, clip, "--force")
    _one_error(rc, err, "is the BVH file being converted")
    assert clip.read_bytes() == before


@pytest.mark.parametrize(
    "name, says",
    [
        ("sh\n010.usda", "control character '\\n'"),
        ("sh\x7f010.usda", "control character '\\x7f'"),
        ("sh\x85010.usda", "control character '\\x85'"),
        (".sh010.usda", "its name starts with a dot"),
        ("a" * 240 + ".usda", "give it a shorter name"),
        ("sh010.tween.v001.usda", "is named like a fill layer"),
        ("sh010.review.v002.usdc", "is named like a review layer"),
    ],
)
def test_convert_refuses_a_shot_name_the_fill_refuses(tmp_path, monkeypatch, capsys, name, says):
    """Convert wrote these shots (exit 0), then `tween fill` refused them (a newline: a USD
    error after the plan was said). Refused up front by the fill's own check, nothing written."""
    from pipeline.errors import ShotError, printable
    from pipeline.usd.write import check_shot_name

    out = tmp_path / name
    rc, err = tween(monkeypatch, capsys, "convert", BANDAI_CLIP, out)
    _one_error(rc, err, f"tween: error: {printable(out)}: ", says)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ShotError, match="control character|starts with a dot|shorter name|not a shot"):
        check_shot_name(str(out))  # the fill refuses the same name


def test_convert_leaves_a_read_only_folder_alone_even_for_root(tmp_path, monkeypatch, capsys):
    """As the fill's layers: the mode bits say read-only (a published folder), whoever runs it."""
    ro = tmp_path / "published"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        rc, err = tween(monkeypatch, capsys, "convert", BANDAI_CLIP, ro / "s.usda")
        _one_error(rc, err, str(ro / "s.usda"), "is read-only")
        assert list(ro.iterdir()) == []
    finally:
        ro.chmod(0o755)


def test_library_build_of_a_file_says_so(tmp_path, monkeypatch, capsys):
    rc, err = tween(monkeypatch, capsys, "library", "build", BANDAI_CLIP, "--out", tmp_path / "lib")
    _one_error(rc, err, str(BANDAI_CLIP), "is a file, not a folder of takes")
    assert not (tmp_path / "lib").exists()


@pytest.mark.parametrize("frame_time", ["inf", "1e-12", "1e12"])
def test_a_frame_time_no_take_has_is_refused(tmp_path, frame_time, monkeypatch, capsys):
    text = gzip.decompress(BANDAI_CLIP.read_bytes()).decode()
    lines = [f"Frame Time: {frame_time}" if ln.startswith("Frame Time:") else ln for ln in text.splitlines()]
    src = tmp_path / "odd.bvh"
    src.write_text("\n".join(lines) + "\n")
    rc, err = tween(monkeypatch, capsys, "convert", src, tmp_path / "odd.usda")
    _one_error(rc, err, str(src), "Frame Time")
    assert not (tmp_path / "odd.usda").exists()


def test_a_start_where_frames_would_collapse_is_refused(tmp_path, monkeypatch, capsys):
    rc, err = tween(monkeypatch, capsys, "convert", BANDAI_CLIP, tmp_path / "s.usda", "--start", "1e300")
    _one_error(rc, err, "--start")
    assert not (tmp_path / "s.usda").exists()


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes here")
def test_convert_refuses_a_fifo_instead_of_waiting_on_it(tmp_path, monkeypatch, capsys):
    fifo = tmp_path / "f.bvh"
    os.mkfifo(fifo)
    rc, err = tween(monkeypatch, capsys, "convert", fifo, tmp_path / "f.usda")
    _one_error(rc, err, str(fifo), "not a regular file")


def test_a_gzip_bomb_stops_at_the_size_cap(tmp_path, monkeypatch):
    bomb = tmp_path / "bomb.bvh.gz"
    with gzip.open(bomb, "wb") as f:
        f.write(b"HIERARCHY\n" + b"x" * 300_000)
    monkeypatch.setattr(bvh, "MAX_BYTES", 100_000)
    with pytest.raises(MotionFormatError, match="of text: not a BVH take"):
        bvh.read_bvh(bomb)


def test_an_instanced_character_is_one_line_naming_the_instance(tmp_path, monkeypatch, capsys):
    from pxr import Usd, UsdGeom

    char = tmp_path / "char.usda"
    char.write_bytes(SHOT.read_bytes())
    src = Usd.Stage.Open(str(char))
    top = src.GetDefaultPrim() or next(iter(src.GetPseudoRoot().GetChildren()))
    walker = next(c for c in top.GetChildren() if any(True for _ in Usd.PrimRange(c)))
    shot = tmp_path / "shot.usda"
    stage = Usd.Stage.CreateNew(str(shot))
    for get, put in ((src.GetTimeCodesPerSecond, stage.SetTimeCodesPerSecond),
                     (src.GetFramesPerSecond, stage.SetFramesPerSecond),
                     (src.GetStartTimeCode, stage.SetStartTimeCode), (src.GetEndTimeCode, stage.SetEndTimeCode)):  # fmt: skip
        put(get())
    UsdGeom.SetStageUpAxis(stage, UsdGeom.GetStageUpAxis(src))
    UsdGeom.SetStageMetersPerUnit(stage, UsdGeom.GetStageMetersPerUnit(src))
    stage.SetDefaultPrim(stage.DefinePrim(str(top.GetPath())))
    inst = stage.DefinePrim(str(walker.GetPath()))
    inst.GetReferences().AddReference("./char.usda", walker.GetPath())
    inst.SetInstanceable(True)
    stage.Save()
    rc, err = tween(monkeypatch, capsys, "fill-local", shot)
    _one_error(rc, err, str(shot), "instanceable = false", str(walker.GetPath()))
    assert "__Prototype" not in err and sorted(p.name for p in tmp_path.iterdir()) == [
        "char.usda",
        "shot.usda",
    ]


def _crowd_shot(tmp_path: Path, bind_inside: bool = False) -> Path:
    """A crowd's layout: the example's character (SkelRoot, Skeleton, mesh) as an asset without
    its animation, placed in the shot as an instance; the animation lives outside it
    (/World/Anims/Walk), bound on the instance prim, so the Skeleton, an instance proxy,
    inherits the binding. ``bind_inside``: the character comes from a class instead, whose
    Skeleton binds the animation itself, inside the instance."""
    from pxr import Sdf, Usd, UsdSkel

    shot = tmp_path / "crowd.usda"
    shot.write_bytes(SHOT.read_bytes())
    stage = Usd.Stage.Open(str(shot))
    layer = stage.GetRootLayer()
    anim, skel = "/World/Walker/Skel/Anim", "/World/Walker/Skel"
    layer.GetPrimAtPath("/World").nameChildren.append(
        Sdf.PrimSpec(layer.GetPrimAtPath("/World"), "Anims", Sdf.SpecifierDef, "Scope")
    )
    assert Sdf.CopySpec(layer, anim, layer, "/World/Anims/Walk")
    stage.RemovePrim(anim)
    stage.GetPrimAtPath(skel).RemoveProperty("skel:animationSource")
    if bind_inside:
        assert Sdf.CopySpec(layer, "/World/Walker", layer, "/_walker")
        layer.GetPrimAtPath("/_walker").specifier = Sdf.SpecifierClass
        stage.RemovePrim("/World/Walker")
        rel = UsdSkel.BindingAPI.Apply(stage.GetPrimAtPath("/_walker/Skel")).CreateAnimationSourceRel()
        rel.SetTargets(["/World/Anims/Walk"])
        inst = stage.DefinePrim("/World/Walker")
        inst.GetInherits().AddInherit("/_walker")
    else:
        asset = tmp_path / "walker.usda"
        Sdf.Layer.CreateNew(str(asset)).Save()
        out = Sdf.Layer.FindOrOpen(str(asset))
        Sdf.CreatePrimInLayer(out, "/Walker")
        assert Sdf.CopySpec(layer, "/World/Walker", out, "/Walker")
        out.defaultPrim = "Walker"
        out.Save()
        stage.RemovePrim("/World/Walker")
        inst = stage.DefinePrim("/World/Walker")
        inst.GetReferences().AddReference("./walker.usda")
        UsdSkel.BindingAPI.Apply(inst).CreateAnimationSourceRel().SetTargets(["/World/Anims/Walk"])
    inst.SetInstanceable(True)
    stage.Save()
    return shot


def test_an_instanced_character_bound_from_outside_is_filled_through_its_instance(
    tmp_path, monkeypatch, capsys
):
    """The Skeleton is an instance proxy, on which no layer's opinion counts: the fill layer
    rebinds the instance prim it inherits the binding from (it once wrote an over on the
    proxy's path, said "filled", and the review showed the shot's own animation)."""
    from pxr import Usd, UsdSkel

    shot = _crowd_shot(tmp_path)
    before = tree_hashes(tmp_path)
    assert Usd.Stage.Open(str(shot)).GetPrimAtPath("/World/Walker/Skel").IsInstanceProxy()
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--out-dir", tmp_path / "out")
    assert rc == 0, err
    stage = Usd.Stage.Open(str(tmp_path / "out" / "crowd.review.v001.usda"))
    skel = UsdSkel.Skeleton(stage.GetPrimAtPath("/World/Walker/Skel"))
    anim = UsdSkel.Cache().GetSkelQuery(skel).GetAnimQuery()
    assert str(anim.GetPrim().GetPath()) == "/World/Anims/Walk_tween"
    shown = np.array(anim.ComputeJointLocalTransforms(1005.0))
    own = UsdSkel.Cache().GetAnimQuery(UsdSkel.Animation(stage.GetPrimAtPath("/World/Anims/Walk")))
    assert not np.allclose(shown, np.array(own.ComputeJointLocalTransforms(1005.0)))  # the fill shows
    assert {k: v for k, v in tree_hashes(tmp_path).items() if k in before} == before


def test_an_instanced_character_bound_inside_its_instance_is_one_line(tmp_path, monkeypatch, capsys):
    shot = _crowd_shot(tmp_path, bind_inside=True)
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--out-dir", tmp_path / "out")
    _one_error(
        rc,
        err,
        str(shot),
        "/World/Walker/Skel",
        "bound inside an instanced prim",
        "instanceable = false on /World/Walker",
    )
    assert not (tmp_path / "out").exists()


def test_a_take_that_is_a_folder_or_a_device_is_named_so(tmp_path):
    """A --dna take (or a library's) that is a folder or a device said "no such take file"."""
    from pipeline.errors import ShotError
    from pipeline.usd.take import model_take

    for path, says in ((tmp_path, "a folder, not a take file"), (Path("/dev/null"), "not a regular file"),
                       (tmp_path / "none.usda", "file not found")):  # fmt: skip
        with pytest.raises(ShotError, match=says):
            model_take(path)


def test_the_fixture_animation_is_where_the_tests_look():
    assert ANIM.endswith("/Anim")  # the examples' shot names its animation Anim too
    assert _anim_path(SHOT).endswith("/Anim")


def test_review_refuses_a_fills_folder_that_is_not_there(shot, monkeypatch, capsys):
    rc, err = tween(
        monkeypatch, capsys, "review", shot, "--fills", shot.parent / "no-such-folder", "--no-frames"
    )
    _one_error(rc, err, "--fills", "no such folder")
    assert sorted(p.name for p in shot.parent.iterdir()) == [shot.name]


def test_an_animation_naming_a_joint_twice_is_one_line(shot, monkeypatch, capsys):
    from pxr import Usd, UsdSkel, Vt

    stage = Usd.Stage.Open(str(shot))
    anim = UsdSkel.Animation(stage.GetPrimAtPath(_anim_path(shot)))
    joints = list(anim.GetJointsAttr().Get())
    joints[7] = joints[6]
    anim.GetJointsAttr().Set(Vt.TokenArray(joints))
    stage.Save()
    rc, err = tween(monkeypatch, capsys, "fill-local", shot)
    _one_error(rc, err, str(shot), "twice", joints[6].rsplit("/", 1)[-1])
    assert sorted(p.name for p in shot.parent.iterdir()) == [shot.name]


def test_an_out_dir_that_is_a_file_is_named_a_file(shot, tmp_path, monkeypatch, capsys):
    """Before: "is read-only", which sent the TD to check permissions on a file."""
    f = tmp_path / "layers"
    f.write_text("not a folder")
    for out, says in ((f, f"output folder {f} is a file, not a folder"),
                      (f / "sub", f"output folder {f / 'sub'} is under {f}, a file, not a folder")):  # fmt: skip
        rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--out-dir", out)
        _one_error(rc, err, says)
    assert f.read_text() == "not a folder"


def test_a_review_of_a_fill_layer_cut_short_is_one_line_naming_it(shot, tmp_path, monkeypatch, capsys):
    """Before: USD composed the review root without the fill layer it could not parse, and
    `tween review` rendered the unfilled shot, exit 0."""
    out = tmp_path / "layers"
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--out-dir", out, "--model", "spline")
    assert rc == 0, err
    capsys.readouterr()
    fill = next(out.glob("*.tween.v001.usda"))
    fill.write_bytes(fill.read_bytes()[: fill.stat().st_size // 2])
    review = next(out.glob("*.review.v001.usda"))
    rc, err = tween(monkeypatch, capsys, "review", review, "--out", tmp_path / "media", "--size", "160x90")
    _one_error(rc, err, f"{review}: its sublayer {fill} cannot be read as USD")
    assert not (tmp_path / "media").exists()


def test_a_shot_named_in_upper_case_is_converted(tmp_path, monkeypatch, capsys):
    """USD reads `.USDA` as `.usda`; convert refused it ("must end in .usda")."""
    from pxr import Usd

    out = tmp_path / "SH010.USDA"
    rc, err = tween(monkeypatch, capsys, "convert", BANDAI_CLIP, out)
    assert rc == 0, err
    assert out.read_bytes().startswith(b"#usda 1.0") and Usd.Stage.Open(str(out)).GetDefaultPrim()


def test_shots_that_share_a_stem_do_not_share_versions(tmp_path, monkeypatch, capsys):
    """shot.a.usda and shot.b.usda both name their layers shot.tween.vNNN: b's fill went on
    a's series (and with a's --job-id came back as a's layer), so each one's latest fill was
    the other's. b is refused in one line; a's series goes on, under another extension too."""
    a, b = tmp_path / "shot.a.usda", tmp_path / "shot.b.usda"
    a.write_bytes(SHOT.read_bytes())
    b.write_bytes(SHOT.read_bytes())
    rc, err = tween(monkeypatch, capsys, "fill-local", a, "--model", "spline", "--job-id", "J1")
    assert rc == 0, err
    before = tree_hashes(tmp_path)
    for extra in ([], ["--job-id", "J1"]):
        rc, err = tween(monkeypatch, capsys, "fill-local", b, "--model", "spline", *extra)
        _one_error(rc, err, str(b), "which hold the fills of shot.a.usda")
        assert tree_hashes(tmp_path) == before
    rc, err = tween(monkeypatch, capsys, "fill-local", b, "--model", "spline", "--out-dir", tmp_path / "b")
    assert rc == 0, err
    (tmp_path / "shot.a.usd").write_bytes(a.read_bytes())  # the same shot under another format
    a.unlink()
    rc, err = tween(monkeypatch, capsys, "fill-local", tmp_path / "shot.a.usd", "--model", "spline")
    assert rc == 0 and (tmp_path / "shot.tween.v002.usda").is_file(), err


def _sublayering(shot: Path, target: str) -> Path:
    """``shot`` with ``target`` (a path as authored) as its first sublayer."""
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(str(shot))
    layer.subLayerPaths.insert(0, target)
    layer.Save()
    return shot


@pytest.mark.parametrize("kind", ["folder", "device"])
def test_a_sublayer_that_is_a_folder_or_a_device_is_a_missing_asset(shot, kind, monkeypatch, capsys):
    """USD skips such a sublayer without a word: the fill said nothing, recorded
    ``missing_assets: []`` and --strict filled it. Now it counts as a missing sublayer does."""
    import json

    if kind == "folder":
        (shot.parent / "anim.usda").mkdir()
    odd = str(shot.parent / "anim.usda") if kind == "folder" else "/dev/zero"
    _sublayering(shot, "./anim.usda" if kind == "folder" else odd)
    out = shot.parent / "out"
    rc, err = tween(
        monkeypatch, capsys, "fill-local", shot, "--model", "spline", "--out-dir", out, "--strict"
    )
    _one_error(rc, err, str(shot), odd, "--strict")
    assert len(err.strip().splitlines()) == 1 and not out.exists(), err
    monkeypatch.setattr(
        sys, "argv", ["tween", "fill-local", str(shot), "--model", "spline", "--out-dir", str(out)]
    )
    with pytest.raises(SystemExit) as e:
        main()
    res, err = capsys.readouterr()
    assert e.value.code == 0, err
    assert json.loads(res)["missing_assets"] == [odd]
    assert (
        f"tween: warning: {shot}: {odd}: not a regular file; the shot is filled without it"
        in err.splitlines()
    )


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes here")
def test_missing_assets_lists_a_fifo_sublayer_without_waiting_on_it(shot):
    """Reading a FIFO blocks until something writes to it: USD (UsdUtils.ComputeAllDependencies)
    opened it and waited for ever. Run apart, so that a regression fails instead of hanging."""
    import subprocess

    os.mkfifo(shot.parent / "anim.usda")
    _sublayering(shot, "./anim.usda")
    code = "import sys; from pipeline.usd.read import missing_assets; print(missing_assets(sys.argv[1]))"
    r = subprocess.run([sys.executable, "-c", code, str(shot)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout.strip() == repr([str(shot.parent / "anim.usda")]), r.stderr
    # The fill opens the stage with a stand-in for it (it waited for ever there too).
    fill = [sys.executable, "-m", "pipeline.cli", "fill-local", str(shot), "--model", "spline", "--out-dir"]
    r = subprocess.run(
        [*fill, str(shot.parent / "a"), "--strict"], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 2 and "anim.usda" in r.stderr.splitlines()[-1], r.stderr
    r = subprocess.run([*fill, str(shot.parent / "b")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and f"{shot.parent / 'anim.usda'}: not a regular file" in r.stderr, r.stderr


@pytest.mark.parametrize("char", ["\U0001f600", "€"])
def test_a_joint_name_with_a_character_usd_paths_cannot_hold_is_one_line(
    shot, tmp_path, monkeypatch, capsys, char
):
    """USD's reason for refusing the name quotes it cut inside the character; decoding that
    text raised UnicodeDecodeError, an internal error (exit 1)."""
    from pxr import Usd, Vt

    stage = Usd.Stage.Open(str(shot))
    for path in ("/World/Walker/Skel", _anim_path(shot)):
        attr = stage.GetPrimAtPath(path).GetAttribute("joints")
        attr.Set(Vt.TokenArray([str(j).replace("Head", f"Head{char}") for j in attr.Get()]))
    stage.Save()
    before = tree_hashes(tmp_path)
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--out-dir", tmp_path / "out")
    _one_error(rc, err, str(shot), "/World/Walker/Skel", f"Head{char}'", "is not a joint path")
    assert "USD:" not in err and tree_hashes(tmp_path) == before


@pytest.mark.parametrize("opts", [["--trust", "spline"], ["--model", "interp"], []])
def test_a_skeleton_with_two_root_joints_is_one_line(shot, tmp_path, monkeypatch, capsys, opts):
    """UsdSkel allows a second root joint; the fill's own-rig curve built a one-root
    skeleton of it and failed (ValueError, exit 1) wherever the trust chose the spline, then
    it was refused. Now the hierarchy under the root holding the most joints is the character
    (filled), and the second root, which the animation does not list, is left to its rest
    pose as UsdSkel leaves it: one warning line (tests/usd/test_compat_roots_several.py)."""
    from pxr import Gf, Sdf, Usd, Vt

    stage = Usd.Stage.Open(str(shot))
    skel = stage.GetPrimAtPath("/World/Walker/Skel")
    for name in ("joints", "bindTransforms", "restTransforms"):
        attr = skel.GetAttribute(name)
        values = list(attr.Get())
        values.append("Extra" if name == "joints" else Gf.Matrix4d(1))
        attr.Set(Vt.TokenArray(values) if name == "joints" else Vt.Matrix4dArray(values))
    anim = "/World/Walker/Skel/Anim"
    listed = list(stage.GetPrimAtPath(anim).GetAttribute("joints").Get())
    stage.Save()
    before = tree_hashes(tmp_path)
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--out-dir", tmp_path / "out", *opts)
    assert rc == 0, err
    warnings = [ln for ln in err.splitlines() if "root joints" in ln]
    assert len(warnings) == 1 and "error" not in err, err
    assert warnings[0].startswith(
        f"tween: warning: {shot} /World/Walker/Skel: 2 root joints ('Hips', 'Extra'): the character is "
        "the hierarchy under 'Hips' (21 joints); the 1 joint under the other roots (the first is 'Extra')"
    ), err
    after = tree_hashes(tmp_path)
    assert {k: after[k] for k in before} == before  # the shot untouched
    layer = Sdf.Layer.FindOrOpen(str(tmp_path / "out" / "sh010.tween.v001.usda"))
    spec = layer.GetPrimAtPath(anim + "_tween")
    assert list(spec.attributes["joints"].default) == listed  # the animation's joints, no more
