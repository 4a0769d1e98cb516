"""A reference clip the rig cannot learn from is one line naming the file (and the USD prim),
exit 2, nothing written: a skeleton of several roots, uneven time samples far outside the
stage range, fewer than two frames, values beyond any character (rate, unit, lengths),
complex numbers, ``--skeleton`` for a source holding one skeleton (pipeline.rig.source)."""

from __future__ import annotations

import math
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
from cli_contract import refused
from test_rig_core import REPO, walk

from pipeline.rig.source import save_npz

WALK = REPO / "examples" / "sh010_walk.usda"
TINY = ["--schedule", "tiny", "--iters", "2"]


def _both(clip: Path, capsys, tmp_path: Path, *extra) -> list[str]:
    """The error lines of ``rig-extract`` and ``train-rig`` on ``clip`` (each refused, nothing
    written under ``tmp_path``)."""
    pytest.importorskip("torch")
    out = tmp_path / "out"
    out.mkdir(exist_ok=True)
    lines = [refused(["rig-extract", clip, out / "x.npz", *extra], capsys, tmp_path)]
    lines.append(refused(["train-rig", clip, "--out", out / "m", *TINY, *extra], capsys, tmp_path))
    return lines


def _shot(tmp_path: Path, name: str, edit=None) -> Path:
    """A copy of the example walk (edited through pxr by ``edit(stage)``)."""
    path = tmp_path / f"{name}.usda"
    shutil.copy(WALK, path)
    if edit:
        from pxr import Usd

        stage = Usd.Stage.Open(str(path))
        edit(stage)
        stage.GetRootLayer().Save()
    return path


def _npz(tmp_path: Path, name: str, **change) -> Path:
    path = tmp_path / f"{name}.npz"
    save_npz(walk(48), path)
    with np.load(path) as z:
        arrays = dict(z) | change
    np.savez(path, **arrays)
    return path


def test_a_skeleton_of_several_roots_names_the_file_and_prim(tmp_path, capsys):
    """Before: ValueError "joint 'Neck' comes before its parent" (exit 1)."""
    pytest.importorskip("pxr")
    text = WALK.read_text()
    cases = {
        "not_tree": text.replace('"Hips/Spine/Chest/Neck', '"Foo/Neck'),
        "two_roots": text.replace('"Hips/UpperLeg_L"', '"Other"'),
    }
    for name, body in cases.items():
        shot = tmp_path / f"{name}.usda"
        shot.write_text(body)
        for line in _both(shot, capsys, tmp_path):
            assert line.startswith(
                f"tween: error: {shot} /World/Walker/Skel: skeleton topology: 2 root joints"
            )
    two = _npz(tmp_path, "two", parents=np.array([-1, 0, 1, -1, 3, 4, 0, 6, 7]))
    for line in _both(two, capsys, tmp_path):
        assert line == (
            f"tween: error: {two}: parents: 2 root joints ('hips', 'l_hip'); "
            "a rig is one hierarchy under one root joint"
        )


def test_uneven_samples_far_outside_the_stage_range_are_refused_before_reading(tmp_path, capsys):
    """Before: a sample at 1e9 read every frame up to it (MemoryError for 313 GiB)."""
    pytest.importorskip("pxr")

    def far(t, end=None):
        def edit(stage):
            anim = stage.GetPrimAtPath("/World/Walker/Skel/Anim")
            for attr in (anim.GetAttribute("rotations"), anim.GetAttribute("translations")):
                attr.Set(attr.Get(1097), t)
            if end:
                stage.SetEndTimeCode(end)

        return edit

    shot = _shot(tmp_path, "far", far(1e9))
    for line in _both(shot, capsys, tmp_path):
        assert line == (
            f"tween: error: {shot} /World/Walker/Skel/Anim: time sample 1e+09 is outside the stage range 1001-1097"
        )
    long = _shot(tmp_path, "long", far(3e6, end=3e6))  # inside the range, over the frame cap
    for line in _both(long, capsys, tmp_path):
        assert line == f"tween: error: {long}: the stage range 1001-3e+06 spans more than 1,000,000 frames"


def test_fewer_than_two_frames_are_refused(tmp_path, capsys):
    """Before: a 0-frame .npz was an IndexError in training, a 1-frame BVH extracted."""
    m = walk(48)
    zero = _npz(tmp_path, "zero", rotations=m.rotations[:0], root_positions=m.root_positions[:0])
    for line in _both(zero, capsys, tmp_path):
        assert line == f"tween: error: {zero}: 0 frame(s): a clip to learn from needs at least 2"
    bvh = tmp_path / "one.bvh"
    bvh.write_text(
        "HIERARCHY\nROOT hips\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition "
        "Zrotation Xrotation Yrotation\n JOINT spine\n {\n  OFFSET 0 10 0\n  CHANNELS 3 "
        "Zrotation Xrotation Yrotation\n  End Site\n  {\n   OFFSET 0 10 0\n  }\n }\n}\n"
        "MOTION\nFrames: 1\nFrame Time: 0.033333\n0 90 0 0 0 0 0 0 0\n"
    )
    for line in _both(bvh, capsys, tmp_path):
        assert line == f"tween: error: {bvh}: 1 frame(s): a clip to learn from needs at least 2"


def test_values_beyond_any_character_are_refused(tmp_path, capsys):
    """Before: offsets ×1e30 wrote NaN into rig.json; 1e-300 fps, 1e300 metersPerUnit and a
    complex rotations array (a ComplexWarning) trained."""
    m = walk(48)
    cases = {
        _npz(
            tmp_path, "offsets", offsets=m.skeleton.offsets * 1e30
        ): "its offsets hold a value beyond ±1e+07 units",
        _npz(tmp_path, "root", root_positions=m.root_positions.astype(np.float64) * 1e300): (
            "its root positions hold NaN or infinite values"  # float64 beyond float32: no warning
        ),
        _npz(tmp_path, "slow", fps=np.array(1e-300)): "frame rate 1e-300: must be from 1 to 1000 fps",
        _npz(tmp_path, "fast", fps=np.array(2000.0)): "frame rate 2000: must be from 1 to 1000 fps",
        _npz(tmp_path, "big", meters_per_unit=np.array(1e300)): "meters per unit 1e+300 is not a unit",
        _npz(tmp_path, "small", meters_per_unit=np.array(1e-300)): "meters per unit 1e-300 is not a unit",
        _npz(tmp_path, "complex", rotations=m.rotations.astype(np.complex64)): (
            "rotations: complex64 values, expected real numbers"
        ),
        _npz(tmp_path, "fps2", fps=np.array([30.0, 60.0])): "fps: an array of shape (2,), expected one value",
    }
    for clip, says in cases.items():
        for line in _both(clip, capsys, tmp_path):
            assert line.startswith(f"tween: error: {clip}: {says}"), line


def test_unknown_schedule_and_skeleton_for_an_npz_are_refused(tmp_path, capsys):
    """Before: ``--schedule foo --iters 2`` and ``--skeleton`` on an .npz were accepted."""
    pytest.importorskip("torch")
    clip = tmp_path / "c.npz"
    save_npz(walk(48), clip)
    argv = ["train-rig", clip, "--out", tmp_path / "m", "--schedule", "foo"]
    for extra in ([], ["--iters", "2"]):
        line = refused(argv + extra, capsys, tmp_path)
        assert line == "tween: error: --schedule 'foo': must be tiny, reduced or paper"
    for line in _both(clip, capsys, tmp_path, "--skeleton", "/X"):
        assert line == f"tween: error: {clip}: --skeleton applies to USD shots; an .npz holds one skeleton"


@pytest.mark.parametrize("where", ["position", "end site"])
def test_huge_bvh_values_are_one_line_without_warnings(tmp_path, capsys, where):
    """Before: RuntimeWarning lines (overflow) came before the error line."""
    pos, end = ("1e38 1e38 1e38", "0 10 0") if where == "position" else ("0 90 0", "1e300 5 0")
    bvh = tmp_path / "huge.bvh"
    bvh.write_text(
        "HIERARCHY\nROOT hips\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition "
        "Zrotation Xrotation Yrotation\n JOINT spine\n {\n  OFFSET 0 10 0\n  CHANNELS 3 "
        f"Zrotation Xrotation Yrotation\n  End Site\n  {{\n   OFFSET {end}\n  }}\n }}\n}}\n"
        f"MOTION\nFrames: 2\nFrame Time: 0.033333\n{pos} 0 0 0 0 0 0\n0 90 0 0 0 0 0 0 0\n"
    )
    for line in _both(bvh, capsys, tmp_path):
        assert line.startswith(f"tween: error: {bvh}:") and "beyond" in line, line


def test_empty_or_multi_line_option_texts_are_refused_by_train_rig_itself(tmp_path, capsys):
    """``--frames ''`` learnt the whole clip and ``--name a/b`` named the model a path; before,
    only submit-train-rig refused them (TrainRigOptions.check serves both)."""
    pytest.importorskip("torch")
    clip = tmp_path / "c.npz"
    save_npz(walk(48), clip)
    for flag, value, says in (("--frames", "", "empty; leave it out for the default"),
                              ("--skeleton", " ", "empty; leave it out for the default"),
                              ("--name", "", "empty; leave it out for the default"),
                              ("--name", "a/b", "a model name, not a path"),
                              ("--licence", "CC BY\n4.0", "must be one line of printable text"),
                              ("--credit", "", "empty; leave it out for the default")):  # fmt: skip
        line = refused(["train-rig", clip, "--out", tmp_path / "m", *TINY, flag, value], capsys, tmp_path)
        assert line.startswith(f"tween: error: {flag} ") and says in line, line


def _declaring(tmp_path: Path, stem: str, data: bool, **declared) -> Path:
    """The walk's .npz with each ``declared`` member (key: (shape, dtype)) replaced by one whose
    header declares that shape, followed by as many compressed zero bytes (``data``) or by
    nothing: a file of kilobytes, whatever it declares (no array that large is made here)."""
    from numpy.lib import format as fmt

    path = tmp_path / f"{stem}.npz"
    arrays = {k: np.asarray(v) for k, v in np.load(_npz(tmp_path, stem)).items()}
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for k, a in arrays.items():
            with z.open(f"{k}.npy", "w", force_zip64=True) as f:
                if k not in declared:
                    fmt.write_array(f, a)
                    continue
                shape, dtype = declared[k]
                fmt.write_array_header_1_0(
                    f, {"descr": fmt.dtype_to_descr(np.dtype(dtype)), "fortran_order": False, "shape": shape}
                )
                left, zeros = math.prod(shape) * np.dtype(dtype).itemsize * data, bytes(1 << 24)
                while left > 0:
                    f.write(zeros[: min(left, len(zeros))])
                    left -= len(zeros)
    return path


def test_an_npz_declaring_more_frames_than_a_shot_is_refused_before_reading(tmp_path, capsys):
    """Before: a 2.6 MB .npz of compressed zeros declaring millions of frames made train-rig
    take 16 GB. Now its headers are read first: one line naming the file, the count and the cap."""
    clip = _declaring(
        tmp_path, "long", True, rotations=((2_000_000, 9, 4), "<f4"), root_positions=((2_000_000, 3), "<f4")
    )
    assert clip.stat().st_size < 1_000_000  # 312 MB of zeros
    for line in _both(clip, capsys, tmp_path):
        assert line == f"tween: error: {clip}: rotations: 2,000,000 frames; a clip holds at most 1,000,000"
    assert not any((tmp_path / "out").iterdir())


def test_an_npz_declaring_too_many_joints_or_bytes_is_refused_before_reading(tmp_path, capsys):
    """Joint counts and string lengths come from the file too: 20,000 names, or a name of 1.2 GB."""
    joints = _declaring(tmp_path, "joints", False, names=((20_000,), "<U8"))
    for line in _both(joints, capsys, tmp_path):
        assert line == f"tween: error: {joints}: names: 20,000 joints; a clip's rig has at most 10,000"
    big = _declaring(tmp_path, "bytes", False, name=((), "<U300000000"))
    for line in _both(big, capsys, tmp_path):  # 1.2 GB, and the bytes of the walk's own arrays
        assert line.startswith(f"tween: error: {big}: its arrays hold 1,200,0"), line
        assert line.endswith(" bytes; a clip holds at most 1 GiB"), line
    assert not any((tmp_path / "out").iterdir())
