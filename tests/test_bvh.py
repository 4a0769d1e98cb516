"""BVH reading of every shipped clip, round trips, per-source root rules and malformed input."""

import gzip

import numpy as np
import pytest

from pipeline.errors import MotionFormatError
from pipeline.motion.bvh import read_bvh, write_bvh

BANDAI_JOINTS = 21


def test_reads_every_bandai_and_cmu_file(data_dir):
    bandai = sorted((data_dir / "bandai_namco").glob("dataset-*/*.bvh.gz"))
    cmu = sorted((data_dir / "cmu_iclone").glob("*.bvh.gz"))
    assert len(bandai) > 3000 and len(cmu) > 50
    for f in bandai:
        m = read_bvh(f)
        assert len(m.skeleton) == BANDAI_JOINTS and m.skeleton.names[0] == "Hips", f
        assert m.fps == 30 and len(m) > 0
        assert np.isfinite(m.rotations).all() and np.isfinite(m.root_positions).all()
    for f in cmu:
        m = read_bvh(f)
        # RL_BoneRoot-wrapped files are folded to the same 100 joints.
        assert len(m.skeleton) == 100 and m.skeleton.names[0] == "CC_Base_Hip", f
        assert m.fps == 60


def lowest_point(m):
    return m.positions()[:, :, 1].min(axis=1)


def test_cmu_root_rule_puts_feet_on_ground(data_dir):
    f = data_dir / "cmu_iclone" / "001_01.bvh.gz"
    m = read_bvh(f)  # rule "add" picked for cmu_iclone
    low = lowest_point(m)
    assert 0 < np.median(low) < 15  # ankles/toes a few cm above the ground
    wrong = read_bvh(f, root_position="replace")
    assert np.median(lowest_point(wrong)) < -80  # the documented ~96 cm below the ground


def test_cmu_z_up_wrapped_rig_is_y_up_after_fk(data_dir):
    f = data_dir / "cmu_iclone" / "002_01.bvh.gz"
    with gzip.open(f, "rt") as fh:
        assert "RL_BoneRoot" in fh.read(300)
    m = read_bvh(f)
    pos = m.positions()
    assert 0 < np.median(lowest_point(m)) < 15
    head = pos[:, m.skeleton.index("CC_Base_Head"), 1]
    assert np.median(head) > 140  # standing, Y up


def test_bandai_feet_on_ground(bandai_clip):
    m = read_bvh(bandai_clip)
    assert 0 < np.median(lowest_point(m)) < 10


@pytest.mark.parametrize("order", ["ZXY", "XYZ"])
def test_write_read_round_trip(tmp_path, bandai_clip, order):
    m = read_bvh(bandai_clip)
    out = tmp_path / ("rt.bvh.gz" if order == "ZXY" else "rt.bvh")
    write_bvh(m, out, order=order)
    back = read_bvh(out, root_position="replace")
    assert back.skeleton == m.skeleton
    assert back.fps == m.fps and len(back) == len(m)
    np.testing.assert_allclose(back.root_positions, m.root_positions, atol=1e-5)
    dots = np.abs((back.rotations.astype(np.float64) * m.rotations).sum(-1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-6)
    np.testing.assert_allclose(back.positions(), m.positions(), atol=1e-4)


GOOD = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 5 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0333333
0 90 0 0 0 0 10 0 0
1 90 0 0 0 0 20 0 0
"""


def write(tmp_path, text, name="bad.bvh"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_good_minimal_file(tmp_path):
    m = read_bvh(write(tmp_path, GOOD, "good.bvh"))
    assert m.skeleton.names == ("Hips", "Spine") and len(m) == 2 and m.fps == 30
    assert 1 in m.skeleton.end_sites


@pytest.mark.parametrize(
    "text,line,message",
    [
        (GOOD.rsplit("\n", 2)[0] + "\n", 19, "1 of 2 frames"),  # truncated
        (GOOD.replace("1 90 0 0 0 0 20 0 0", "1 90 0 0 0 0 20 0"), 20, "8 values, expected 9"),
        (GOOD.replace("1 90 0 0 0 0 20 0 0", "1 90 0 0 abc 0 20 0 0"), 20, "non-numeric value 'abc'"),
        (GOOD.replace("Frames: 2", "Frames: 0"), 17, "zero frames"),
        (GOOD.replace("CHANNELS 3 Zrotation", "CHANNELS 4 Zrotation"), 9, "CHANNELS 4 lists 3"),
        (GOOD.replace("OFFSET 0 10 0", "OFFSET 0 ten 0"), 8, "non-numeric OFFSET"),
        (GOOD.split("MOTION")[0], 15, "before MOTION"),
        ("", 1, "expected HIERARCHY"),
    ],
)
def test_malformed_files_name_file_and_line(tmp_path, text, line, message):
    p = write(tmp_path, text)
    with pytest.raises(MotionFormatError) as err:
        read_bvh(p)
    assert str(err.value).startswith(f"{p}:{line}: "), str(err.value)
    assert message in str(err.value)


def test_missing_and_corrupt_gzip(tmp_path):
    with pytest.raises(MotionFormatError, match="file not found"):
        read_bvh(tmp_path / "nope.bvh")
    p = tmp_path / "x.bvh.gz"
    p.write_bytes(b"not gzip at all")
    with pytest.raises(MotionFormatError, match="cannot read"):
        read_bvh(p)
