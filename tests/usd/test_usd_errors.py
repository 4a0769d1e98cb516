"""Bad input: one-line error naming the shot (and prim), non-zero exit, no output left behind."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from usd_fixtures import ANIM, ELEPHANT, FIGURE, SIMPLE, bandai_shot, tree_hashes

from pipeline.errors import ShotError, TweenError
from pipeline.fill.api import FillOptions, fill_shot


def _edit(shot, fn):
    from pxr import Usd, UsdSkel

    stage = Usd.Stage.Open(str(shot))
    fn(stage, UsdSkel.Animation(stage.GetPrimAtPath(ANIM)))
    stage.GetRootLayer().Save()


def _fails(shot, out, match, prim=None, model="interp", **kw):
    with pytest.raises(TweenError) as ei:
        fill_shot(str(shot), FillOptions(model=model, out_dir=str(out), **kw))
    msg = str(ei.value)
    assert "\n" not in msg and str(shot) in msg and match in msg, msg
    if prim:
        assert prim in msg, msg
    assert not out.exists() or not any(out.iterdir()), list(out.iterdir())
    return msg


def test_missing_and_unreadable_files(tmp_path):
    _fails(tmp_path / "nope.usda", tmp_path / "o", "file not found")
    bad = tmp_path / "junk.usda"
    bad.write_text("#usda 1.0\n( this is not usd\n")
    _fails(bad, tmp_path / "o", "cannot open as USD")
    binary = tmp_path / "junk.usdc"
    binary.write_bytes(b"\x00\x01garbage" * 10)
    _fails(binary, tmp_path / "o", "cannot open as USD")


def test_stage_without_skeleton(tmp_path):
    from pxr import Usd, UsdGeom

    p = tmp_path / "empty.usda"
    stage = Usd.Stage.CreateNew(str(p))
    UsdGeom.Xform.Define(stage, "/World")
    stage.GetRootLayer().Save()
    _fails(p, tmp_path / "o", "no SkelRoot holds a skeleton with a bound SkelAnimation")


def test_fewer_than_two_keys(tmp_path):
    shot = bandai_shot(tmp_path / "one.usda", frames=21, keys_every=10)

    def one_key(stage, anim):
        for a in (anim.GetRotationsAttr(), anim.GetTranslationsAttr()):
            for t in a.GetTimeSamples()[1:]:
                a.ClearAtTime(t)

    _edit(shot, one_key)
    _fails(shot, tmp_path / "o", "1 key(s); at least two are needed", prim=ANIM)


def test_keys_outside_stage_range(tmp_path):
    shot = bandai_shot(tmp_path / "k.usda", frames=21, keys_every=10)
    _fails(shot, tmp_path / "o", "key 900 is outside the stage range 1001-1021", prim=ANIM, keys="900,1010")


def test_nan_values(tmp_path):
    from pxr import Vt

    shot = bandai_shot(tmp_path / "nan.usda", frames=21, keys_every=10)

    def nan(stage, anim):
        q = np.array(anim.GetRotationsAttr().Get(1011))
        q[3] = np.nan
        anim.GetRotationsAttr().Set(Vt.QuatfArray.FromNumpy(q), 1011)

    _edit(shot, nan)
    _fails(shot, tmp_path / "o", "NaN or infinite values at time 1011", prim=ANIM)


def test_joint_count_mismatch(tmp_path):
    from pxr import Vt

    shot = bandai_shot(tmp_path / "jc.usda", frames=21, keys_every=10)

    def short(stage, anim):
        q = np.array(anim.GetRotationsAttr().Get(1011))[:15]
        anim.GetRotationsAttr().Set(Vt.QuatfArray.FromNumpy(np.ascontiguousarray(q)), 1011)

    _edit(shot, short)
    _fails(shot, tmp_path / "o", "rotations holds 15 values for 21 joints at time 1011", prim=ANIM)


def test_real_rigs_the_model_cannot_map_are_refused(tmp_path):
    before = tree_hashes(ELEPHANT.parent)
    human = str(Path(__file__).parents[2] / "models" / "default")  # the human model, no rig models
    msg = _fails(
        ELEPHANT,
        tmp_path / "o",
        "not a humanoid",
        prim="/SoC_ElephantWithMonochord/Object/Elefant/_skel",
        model=human,
    )
    assert "rig refused" in msg
    assert tree_hashes(ELEPHANT.parent) == before
    _fails(FIGURE, tmp_path / "o", "joints do not map onto the model skeleton", model=human)
    _fails(SIMPLE, tmp_path / "o", "joints do not map onto the model skeleton", model=human)


def test_shot_error_type_and_cli_one_line_exit_2(tmp_path):
    with pytest.raises(ShotError):
        fill_shot(str(tmp_path / "x.usda"), FillOptions())
    shot = bandai_shot(tmp_path / "k.usda", frames=21, keys_every=10)
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "pipeline.cli",
            "fill-local",
            str(shot),
            "--keys",
            "1001",
            "--out",
            str(tmp_path / "o"),
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and r.stdout == ""
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and str(shot) in lines[0] and ANIM in lines[0] and "at least two" in lines[0]
    assert not (tmp_path / "o").exists()


def test_usd_messages_lose_the_cpp_addresses_they_name_objects_by():
    """A refusal carried USD's "(instantiating stage on stage @shot.usda@ <0x560a886dc790>)",
    an address that differs each run and tells the user nothing."""
    from pipeline.usd.diagnostics import _one_line

    text = "Could not load sublayer @m.usda@\n (instantiating stage on stage @shot.usda@ <0x560a886dc790>)"
    assert _one_line(text) == "Could not load sublayer @m.usda@ (instantiating stage on stage @shot.usda@)"
