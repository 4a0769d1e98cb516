"""`tween rig-extract --frames` and `train-rig --frames`: START:STOP frame indices from the
clip's first frame; STOP left out runs to the end; a negative index is refused (it read as
"to the end", whatever its value)."""

from __future__ import annotations

import numpy as np
import pytest
from cli_contract import refused, succeeded
from test_rig_core import walk

from pipeline.errors import TweenError
from pipeline.rig.source import load_rig_source, parse_frames, save_npz


def test_parse_frames():
    assert parse_frames("0:1511") == (0, 1511)
    assert parse_frames("100:") == (100, None)
    assert parse_frames(":20") == (0, 20)
    assert parse_frames("") is None and parse_frames(None) is None
    for bad in ("0:-5", "-3:10", "-1:"):
        with pytest.raises(TweenError, match="count from 0"):
            parse_frames(bad)
    with pytest.raises(TweenError, match="expected START:STOP"):
        parse_frames("5")


def test_rig_extract_frames_cut_the_clip_and_a_negative_stop_is_refused(tmp_path, capsys):
    clip = tmp_path / "c.npz"
    save_npz(walk(48), clip)
    assert len(load_rig_source(clip, None, parse_frames("10:"))) == 38
    assert len(load_rig_source(clip, None, parse_frames("4:12"))) == 8
    out = tmp_path / "out"
    out.mkdir()
    line = refused(["rig-extract", clip, out / "x.npz", "--frames", "0:-5"], capsys, out)
    assert line == "tween: error: --frames '0:-5': frame indices count from 0 (the clip's first frame)"
    line = refused(["rig-extract", clip, out / "x.npz", "--frames", "0:1"], capsys, out)
    assert (
        line == f"tween: error: {clip}: frames 0:1 hold 1 frame; a clip needs at least 2"
    )  # not "not inside"
    line = refused(["rig-extract", clip, out / "x.npz", "--frames", "40:60"], capsys, out)
    assert line == f"tween: error: {clip}: frames 40:60 are not inside the clip's 48 frames"
    succeeded(["rig-extract", clip, out / "x.npz", "--frames", "10:"], capsys)
    with np.load(out / "x.npz") as z:
        assert len(z["rotations"]) == 38


def test_contacts_that_name_no_joint_are_refused(tmp_path, capsys):
    """Before: ``--contacts ','`` trained a model with no foot contacts at all."""
    from pipeline.rig.options import TrainRigOptions

    for bad in (",", " , ", ""):
        with pytest.raises(TweenError, match="names no joint"):
            TrainRigOptions(contacts=bad).check()
    assert TrainRigOptions(contacts="l_ankle, r_ankle").check().contacts == "l_ankle, r_ankle"
    clip = tmp_path / "c.npz"
    save_npz(walk(48), clip)
    line = refused(["train-rig", clip, "--out", tmp_path / "m", "--contacts", ","], capsys, tmp_path)
    assert line.startswith("tween: error: --contacts ',': names no joint")
    assert not (tmp_path / "m").exists()
