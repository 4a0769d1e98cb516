"""BVH reading of every shipped clip, round trips, per-source root rules and malformed input."""

import gzip
import os
import warnings

import numpy as np
import pytest

from pipeline.errors import MotionFormatError
from pipeline.motion.bvh import read_bvh, write_bvh

BANDAI_JOINTS = 21


def test_reads_the_bandai_and_cmu_files(data_dir):
    """Every CMU file and every 10th Bandai file (each style and actor is among them); all
    3,000 Bandai files with TWEEN_ALL_DATA=1 (``make test-nightly``), a 100 s read."""
    bandai = sorted((data_dir / "bandai_namco").glob("dataset-*/*.bvh.gz"))
    cmu = sorted((data_dir / "cmu_iclone").glob("*.bvh.gz"))
    assert len(bandai) > 3000 and len(cmu) > 50
    if os.environ.get("TWEEN_ALL_DATA") != "1":
        bandai = bandai[::10]
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
    m = read_bvh(f)  # rule "add", told by the take's content
    low = lowest_point(m)
    assert 0 < np.median(low) < 15  # ankles/toes a few cm above the ground
    wrong = read_bvh(f, root_position="replace")
    assert np.median(lowest_point(wrong)) < -80  # the documented ~96 cm below the ground


def test_the_root_rule_is_told_by_content_not_by_the_folder(data_dir, tmp_path):
    """A CMU take copied out of cmu_iclone read as "replace" (its feet a metre below the
    ground, exit 0): the rule came from the folder's name. A take whose root OFFSET is its
    rest height and whose channels are absolute (most exporters) stays "replace"."""
    import shutil

    f = data_dir / "cmu_iclone" / "001_01.bvh.gz"
    copy = tmp_path / "renamed_take.bvh.gz"
    shutil.copy(f, copy)
    a, b = read_bvh(f), read_bvh(copy)
    np.testing.assert_array_equal(a.root_positions, b.root_positions)
    np.testing.assert_array_equal(a.skeleton.offsets, b.skeleton.offsets)
    assert 0 < np.median(lowest_point(b)) < 15
    plain = tmp_path / "plain.bvh"  # hips 90 cm up in OFFSET and in the channels, feet on the ground
    plain.write_text(
        "HIERARCHY\nROOT Hips\n{\n OFFSET 0 90 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n"
        " JOINT Foot\n {\n  OFFSET 0 -88 0\n  CHANNELS 3 Zrotation Xrotation Yrotation\n"
        "  End Site\n  {\n   OFFSET 0 -2 0\n  }\n }\n}\nMOTION\nFrames: 3\nFrame Time: 0.0333333\n"
        + "".join(f"{x} 90 0 0 0 0 0 0 0\n" for x in (0, 5, 10))
    )
    m = read_bvh(plain)
    np.testing.assert_allclose(m.root_positions[:, 1], 90)  # not 180: the OFFSET is not added
    np.testing.assert_allclose(lowest_point(m), 2, atol=1e-5)


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


# ---- BVH from other tools: channel orders, position channels, rates, encodings ----


def two_joint(root_ch, child_ch, child_offset="0 10 0", frame_time="0.0333333", rows=("",), name="Spine"):
    return (
        "HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n"
        f"  CHANNELS {len(root_ch.split())} {root_ch}\n"
        f"  JOINT {name}\n  {{\n    OFFSET {child_offset}\n    CHANNELS {len(child_ch.split())} {child_ch}\n"
        "    End Site\n    {\n      OFFSET 0 5 0\n    }\n  }\n}\n"
        f"MOTION\nFrames: {len(rows)}\nFrame Time: {frame_time}\n" + "\n".join(rows) + "\n"
    )


@pytest.mark.parametrize("order", ["XYZ", "YXZ", "ZYX", "ZXY", "XZY", "YZX", "XY", "Z"])
def test_any_rotation_order_is_intrinsic_in_channel_order(tmp_path, order):
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(len(order) * 7 + ord(order[0]))
    ang = rng.uniform(-170, 170, (3, 2, len(order)))
    rot = " ".join(f"{a}rotation" for a in order)
    rows = [f"1 2 3 {' '.join(map(str, a[0]))} {' '.join(map(str, a[1]))}" for a in ang]
    p = write(tmp_path, two_joint(f"Xposition Yposition Zposition {rot}", rot, rows=rows), "o.bvh")
    m = read_bvh(p)
    for t in range(3):
        for j in range(2):
            want = Rotation.from_euler(order, ang[t, j], degrees=True)
            assert (want.inv() * Rotation.from_quat(m.rotations[t, j])).magnitude() < 1e-6


def test_position_channels_below_the_root_give_the_bone(tmp_path):
    # Exporters that write 6 channels per joint may leave OFFSET at zero: the channels hold
    # the bone. Channels equal to the OFFSET (Bandai) keep the OFFSET bit for bit.
    ch = "Zposition Xposition Yposition Yrotation Xrotation Zrotation"

    def rig(spine_offset, rows):
        return (
            f"HIERARCHY\nROOT Hips\n{{\n  OFFSET 0 0 0\n  CHANNELS 6 {ch}\n"
            f"  JOINT Spine\n  {{\n    OFFSET {spine_offset}\n    CHANNELS 6 {ch}\n"
            "    End Site\n    {\n      OFFSET 0 5 0\n    }\n  }\n"
            "  JOINT LeftUpLeg\n  {\n    OFFSET 9 -3 0\n    CHANNELS 3 Zrotation Xrotation Yrotation\n"
            "    End Site\n    {\n      OFFSET 0 -40 0\n    }\n  }\n}\n"
            f"MOTION\nFrames: {len(rows)}\nFrame Time: 0.0333333\n" + "\n".join(rows) + "\n"
        )

    rows = ["0 90 0 0 0 0 3 0 12 0 0 0 0 0 0", "1 91 0 0 0 0 3 0 12 0 0 0 0 0 0"]
    m = read_bvh(write(tmp_path, rig("0 0 0", rows), "a.bvh"))
    assert m.skeleton.names == ("Hips", "Spine", "LeftUpLeg")
    np.testing.assert_array_equal(m.skeleton.offsets[1:], [[0, 12, 3], [9, -3, 0]])
    np.testing.assert_array_equal(m.root_positions, [[90, 0, 0], [91, 0, 1]])  # Z X Y order
    rows = ["0 90 0 0 0 0 0.1 0.2 0.30000001 0 0 0 0 0 0"] * 2
    m = read_bvh(write(tmp_path, rig("0.2 0.30000002 0.1", rows), "b.bvh"))
    np.testing.assert_array_equal(m.skeleton.offsets[1], np.float32([0.2, 0.30000002, 0.1]))


def test_root_with_some_position_channels_or_none(tmp_path):
    rows = ["95 0 0 0 0", "96 0 0 0 0"]
    m = read_bvh(
        write(tmp_path, two_joint("Yposition Zrotation Xrotation Yrotation", "Zrotation", rows=rows))
    )
    np.testing.assert_array_equal(m.root_positions, [[0, 95, 0], [0, 96, 0]])
    m = read_bvh(
        write(tmp_path, two_joint("Zrotation Xrotation Yrotation", "Zrotation", rows=["0 0 0 0"] * 2))
    )
    np.testing.assert_array_equal(m.root_positions, 0)


@pytest.mark.parametrize(
    "frame_time,fps",
    [
        ("0.041667", 24),
        ("0.0333333", 30),
        ("0.04", 25),
        ("0.016667", 60),
        ("0.008333", 120),
        ("0.0083333", 120),
    ],
)
def test_frame_time_24_to_120_fps(tmp_path, frame_time, fps):
    text = two_joint("Zrotation Xrotation Yrotation", "Zrotation", frame_time=frame_time, rows=["0 0 0 0"])
    assert read_bvh(write(tmp_path, text)).fps == fps


def test_latin1_utf8_and_bom_names_are_kept(tmp_path):
    text = two_joint("Zrotation Xrotation Yrotation", "Zrotation", rows=["0 0 0 0"], name="Épaule gauche")
    (tmp_path / "l1.bvh").write_bytes(text.encode("latin-1"))
    (tmp_path / "u8.bvh").write_bytes(b"\xef\xbb\xbf" + text.encode("utf-8"))
    (tmp_path / "u8.bvh.gz").write_bytes(gzip.compress(text.replace("Hips", "mixamorig:Hips").encode()))
    assert read_bvh(tmp_path / "l1.bvh").skeleton.names == ("Hips", "Épaule gauche")
    assert read_bvh(tmp_path / "u8.bvh").skeleton.names == ("Hips", "Épaule gauche")
    assert read_bvh(tmp_path / "u8.bvh.gz").skeleton.names == ("mixamorig:Hips", "Épaule gauche")


@pytest.mark.parametrize(
    "edit,line,message",
    [
        (
            ("CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS 3 Zrotation Zrotation Yrotation"),
            9,
            "listed twice",
        ),
        (("    End Site", "    CHANNELS 7 Xrotation\n    End Site"), 10, "CHANNELS 7 lists 1"),
        (
            ("  OFFSET 0 0 0\n", "  OFFSET 0 0 0\n  CHANNELS 3 Xrotation Yrotation Zrotation\n"),
            6,
            "second CHANNELS",
        ),
    ],
)
def test_bad_channel_lists_name_the_line(tmp_path, edit, line, message):
    p = write(tmp_path, GOOD.replace(*edit, 1))
    with pytest.raises(MotionFormatError) as err:
        read_bvh(p)
    assert str(err.value).startswith(f"{p}:{line}: ") and message in str(err.value), str(err.value)


def test_folder_and_overflowing_values_are_refused(tmp_path):
    with pytest.raises(MotionFormatError, match="a folder, not a BVH file"):
        read_bvh(tmp_path)
    # Beyond float32 (a numpy overflow warning on stderr before the line), and finite ones
    # whose products overflow later (the mesh of `tween convert` was NaN): 10 km, 2,700 turns.
    for big, where in (
        (
            GOOD.replace("1 90 0 0 0 0 20 0 0", "1 1e39 0 0 0 0 20 0 0"),
            "20: a value beyond ±1e+06 in frame 1",
        ),
        (GOOD.replace("1 90 0 0 0 0 20 0 0", "1 90 0 0 0 0 2e6 0 0"), "20: a value beyond ±1e+06 in frame 1"),
        (
            GOOD.replace("0 90 0 0 0 0 10 0 0", "3e38 90 0 0 0 0 10 0 0"),
            "19: a value beyond ±1e+06 in frame 0",
        ),
        (GOOD.replace("OFFSET 0 10 0", "OFFSET 0 1e308 0"), "8: OFFSET 0 1e308 0 is beyond ±1e+06"),
        (
            GOOD.replace("OFFSET 0 5 0", "OFFSET 1e300 5 0"),
            "12: OFFSET 1e300 5 0 is beyond ±1e+06",
        ),  # End Site
    ):
        p = write(tmp_path, big)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            with pytest.raises(MotionFormatError) as e:
                read_bvh(p)
        assert str(e.value) == f"{p}:{where}"


def test_tabs_between_the_words_of_frame_time(tmp_path):
    """Exporters that separate with tabs write "Frame\tTime:" (the hierarchy read already)."""
    m = read_bvh(
        write(tmp_path, GOOD.replace("Frame Time:", "Frame\tTime:").replace("Frames: 2", "Frames:\t2"))
    )
    assert len(m) == 2 and m.fps == 30


def test_a_frame_count_over_the_cap_is_refused_from_the_header(tmp_path, capsys):
    """Before: a 218 KB .bvh.gz declaring ``Frames: 5000000`` ran `tween convert` past 120 s
    and 2.1 GB, and `tween rig-extract` wrote a 46-hour clip. Now the header is refused, in one
    line naming the file, the count and the cap, before a frame is read."""
    from cli_contract import refused

    bomb = tmp_path / "bomb.bvh.gz"
    with gzip.open(bomb, "wt") as f:  # the frames it holds do not matter: the header is refused
        f.write(GOOD.replace("Frames: 2", "Frames: 5000000"))
    says = f"{bomb}:17: Frames: 5,000,000 is more than the 1,000,000 a take may hold"
    with pytest.raises(MotionFormatError) as err:
        read_bvh(bomb)
    assert str(err.value) == says
    out = tmp_path / "out"
    out.mkdir()
    for argv in (["convert", bomb, out / "bomb.usda"], ["rig-extract", bomb, out / "bomb.npz"]):
        assert refused(argv, capsys, tmp_path) == f"tween: error: {says}"
    assert not any(out.iterdir())


def test_a_gzip_of_line_breaks_is_refused_before_it_is_split(tmp_path):
    """A few KB of gzip holding 3 million line breaks (or form feeds, which str.splitlines
    also breaks at) was split into a list of millions of lines first: GiBs for a larger one."""
    for name, body in (("breaks", b"\n" * 3_000_000), ("feeds", b"x\x0c" * 3_000_000)):
        bomb = tmp_path / f"{name}.bvh.gz"
        with gzip.open(bomb, "wb") as f:
            f.write(b"HIERARCHY\n" + body)
        with pytest.raises(MotionFormatError) as err:
            read_bvh(bomb)
        if name == "breaks":
            assert str(err.value) == f"{bomb}: more than 2,000,000 lines: not a BVH take"
        else:  # one line, not 3 million: refused as the malformed take it is
            assert "lines" not in str(err.value) and str(bomb) in str(err.value)


# Run in a child process: its address space bounded a little above what it holds after its
# imports, as a host that does not overcommit memory bounds it.
SMALL_ADDRESS_SPACE = """
import resource, sys
from pathlib import Path
from pipeline.motion import bvh
held = next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmSize:")) << 10
room = held + (256 << 20)
resource.setrlimit(resource.RLIMIT_AS, (room, room))
for p in sys.argv[1:]:
    print(len(bvh._open_text(Path(p))))
"""


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="VmSize is read from /proc")
def test_a_small_take_reads_where_memory_is_not_overcommitted(tmp_path, monkeypatch):
    """The text was read with f.read(MAX_BYTES + 1), which reserves 1 GiB first, for any
    file: a 20-line take was a MemoryError where memory is not overcommitted
    (vm.overcommit_memory=2), here an address space 256 MiB above the child's imports. Now
    it is read a chunk at a time, to the same bound, into the same lines."""
    import subprocess
    import sys
    from pathlib import Path

    from pipeline.motion import bvh

    plain = write(tmp_path, GOOD, "small.bvh")
    zipped = tmp_path / "small.bvh.gz"
    zipped.write_bytes(gzip.compress(GOOD.encode()))
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2]), "OPENBLAS_NUM_THREADS": "1"}
    res = subprocess.run(
        [sys.executable, "-c", SMALL_ADDRESS_SPACE, plain, zipped], env=env, capture_output=True, text=True
    )
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.split() == ["20", "20"]
    lines = GOOD.splitlines()
    for chunk in (1, 7, 1 << 24):  # chunks of any size read the lines the whole text was
        monkeypatch.setattr(bvh, "_READ_CHUNK", chunk)
        assert bvh._open_text(plain) == bvh._open_text(zipped) == lines
        monkeypatch.setattr(bvh, "MAX_BYTES", len(GOOD))  # the bound is the file's size: read
        assert bvh._open_text(zipped) == lines
        monkeypatch.setattr(bvh, "MAX_BYTES", len(GOOD) - 1)  # a byte over the bound: refused
        with pytest.raises(MotionFormatError, match="GiB of text: not a BVH take"):
            bvh._open_text(zipped)
        monkeypatch.undo()


def test_a_header_declaring_fewer_or_more_frames_than_held_reads_as_before(tmp_path):
    """Fewer: the frames after the count are not read; more, up to the cap: truncated."""
    assert len(read_bvh(write(tmp_path, GOOD.replace("Frames: 2", "Frames: 1"), "few.bvh"))) == 1
    p = write(tmp_path, GOOD.replace("Frames: 2", "Frames: 1000000"), "more.bvh")
    with pytest.raises(
        MotionFormatError, match=r"more\.bvh:20: file has 2 of 1000000 frames \(truncated\?\)"
    ):
        read_bvh(p)


def chain_bvh(depth: int, fan: int = 0) -> str:
    """A 3-frame take: a chain of ``depth`` joints under the root, and ``fan`` leaf joints
    beside the chain's first joint (the shape of /tmp/scale_audit's gen_deep_bvh.py)."""
    joint = "JOINT j{}\n{{\nOFFSET 0 1 0\nCHANNELS 3 Zrotation Xrotation Yrotation\n"
    text = "HIERARCHY\nROOT r\n{\nOFFSET 0 0 0\nCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n"
    text += "".join(joint.format(f"f{k}") + "}\n" for k in range(fan))
    text += "".join(joint.format(k) for k in range(depth)) + "}\n" * depth + "}\n"
    row = " ".join(["0"] * (6 + 3 * (depth + fan)))
    return text + f"MOTION\nFrames: 3\nFrame Time: 0.0333333\n{row}\n{row}\n{row}\n"


def test_a_hierarchy_too_deep_or_with_too_many_joints_is_refused_in_one_line(tmp_path, capsys):
    """Before: a 1 MB, 3-frame take of 20,000 nested joints took `tween convert` 77 s and
    5.3 GB and wrote a 576 MB shot (USD joint tokens are full paths: N²/2 names). Now the
    hierarchy is refused at the joint past the bound, before MOTION is read."""
    from cli_contract import refused

    # The root is level 1: a chain of 255 below it is as deep as a take may nest.
    assert len(read_bvh(write(tmp_path, chain_bvh(255), "deepest.bvh")).skeleton.names) == 256
    deep = write(tmp_path, chain_bvh(20_000), "deep.bvh")  # j255, level 257, on line 1026
    wide = write(tmp_path, chain_bvh(0, fan=10_000), "wide.bvh")  # 10,001 joints, two levels
    for p, says in (
        (deep, f"{deep}:1026: joints nested more than the 256 levels deep a take may hold"),
        (wide, f"{wide}:50001: more than the 10,000 joints a take may hold"),
    ):
        with pytest.raises(MotionFormatError) as err:
            read_bvh(p)
        assert str(err.value) == says
        out = tmp_path / "out"
        out.mkdir(exist_ok=True)
        assert refused(["convert", p, out / "shot.usdc"], capsys, tmp_path) == f"tween: error: {says}"
        assert not any(out.iterdir())


def test_values_read_a_block_at_a_time_are_those_of_the_whole_text(tmp_path, monkeypatch):
    """The motion is split into values a block of text at a time; blocks of a few characters
    (a line cut at whitespace, a value never) read what the whole text read at once did."""
    from pipeline.motion import bvh

    rng = np.random.default_rng(0)
    words = [f"{v:.{rng.integers(0, 12)}f}" for v in rng.uniform(-1e3, 1e3, 90)]
    seps = rng.choice([" ", "  ", "\t", " \t "], 90)
    rows = [
        "".join(f"{s}{w}" for s, w in zip(seps[k : k + 9], words[k : k + 9], strict=True)) + " "
        for k in range(0, 90, 9)
    ]
    # As written, then all values on one line (read as before: the count is of the whole).
    for body in ("\n".join(rows), "".join(rows)):
        text = GOOD.split("MOTION")[0] + f"MOTION\nFrames: 10\nFrame Time: 0.0333333\n{body}\n"
        whole = np.array(" ".join(text.split("Time: 0.0333333\n")[1].split("\n")).split(), np.float64)
        for size in (1, 5, 17, 1 << 20):
            monkeypatch.setattr(bvh, "_BLOCK_CHARS", size)
            lines = bvh._open_text(write(tmp_path, text, "blocks.bvh"))
            joints, i = bvh._parse_hierarchy(tmp_path / "blocks.bvh", lines)
            data, _, _ = bvh._parse_motion(tmp_path / "blocks.bvh", lines, i, 9)
            assert np.array_equal(data.ravel(), whole), size


def test_reading_the_motion_makes_no_python_string_per_value(tmp_path):
    """The values were split into one Python string each, all at once: about 17 bytes per
    byte of text (a 505 MB take took 8.3 GB). Read a block at a time into one float array,
    8 MB of motion peaks under 2.5 bytes per byte (1.3 now, the floats 0.9 of it; it was 8.4)."""
    import tracemalloc

    from pipeline.motion import bvh

    row = " ".join(["-123.456"] * 9) + "\n"
    frames = 8_000_000 // len(row)
    text = GOOD.split("Frames:")[0] + f"Frames: {frames}\nFrame Time: 0.0333333\n" + row * frames
    p = write(tmp_path, text, "long.bvh")
    lines = bvh._open_text(p)
    joints, i = bvh._parse_hierarchy(p, lines)
    tracemalloc.start()
    try:
        data, _, _ = bvh._parse_motion(p, lines, i, 9)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert data.shape == (frames, 9) and (data == -123.456).all()
    assert peak < 2.5 * len(row) * frames, f"{peak / (len(row) * frames):.1f} bytes per byte of text"


def test_a_line_of_too_many_values_is_counted_without_splitting_it_at_once(tmp_path, monkeypatch):
    """A frame of too many values is named with their count, counted a block at a time."""
    from pipeline.motion import bvh

    monkeypatch.setattr(bvh, "_BLOCK_CHARS", 1000)
    p = write(tmp_path, GOOD.replace("1 90 0 0 0 0 20 0 0", "1 2 " * 5000), "long_line.bvh")
    with pytest.raises(MotionFormatError) as err:
        read_bvh(p)
    assert str(err.value) == f"{p}:20: frame 1 has 10000 values, expected 9"


def _all_at_once(path, root_position=None, fold_root=True):
    """The take's rotations and root positions as read_bvh made them before it worked a block
    of frames at a time: every frame's float64 transforms at once, the root rule from a frame
    in up to 200 of them, the root folded, then cast to float32."""
    from pipeline.motion import bvh
    from pipeline.motion.rotations import quat_apply, quat_mul

    lines = bvh._open_text(path)
    joints, i = bvh._parse_hierarchy(path, lines)
    data = bvh._parse_motion(path, lines, i, sum(len(j.channels) for j in joints))[0]
    trans, rots = bvh._joint_transforms(joints, data, root_position or "replace")
    if root_position is None and "Yposition" in joints[0].channels and joints[0].offset[1]:
        t, r = trans[:: max(1, len(trans) // 200)], rots[:: max(1, len(trans) // 200)]
        pos, world = np.empty(t.shape), np.empty(r.shape)
        for j, jt in enumerate(joints):
            if jt.parent < 0:
                pos[:, j], world[:, j] = t[:, j], r[:, j]
            else:
                pos[:, j] = pos[:, jt.parent] + quat_apply(world[:, jt.parent], t[:, j])
                world[:, j] = quat_mul(world[:, jt.parent], r[:, j])
        low = pos[..., 1].min()
        if abs(low + joints[0].offset[1]) < abs(low):
            trans, rots = bvh._joint_transforms(joints, data, "add")
    if fold_root and bvh._container_root(joints, [jt.parent for jt in joints]):
        trans[:, 1] = trans[:, 0] + quat_apply(rots[:, 0], trans[:, 1])
        rots[:, 1] = quat_mul(rots[:, 0], rots[:, 1])
        trans, rots, joints = trans[:, 1:], rots[:, 1:], joints[1:]
    offsets = bvh._rest_offsets(path, joints, trans[0])  # it reads the first frame only
    return rots.astype(np.float32), trans[:, 0].astype(np.float32), offsets


def test_a_take_read_a_block_of_frames_at_a_time_is_bit_for_bit_the_same(data_dir, monkeypatch):
    """read_bvh made every frame's float64 transforms at once, then cast them: 56 bytes a
    joint-frame beside the values. Made a block at a time (small blocks here: a take spans
    many, the last one short), the rotations, root positions and bones are the same bits: a
    CMU take (root added, RL_BoneRoot folded) read every way, a Bandai take (joint_Root folded)."""
    from pipeline.motion import bvh

    monkeypatch.setattr(bvh, "_BLOCK_JOINT_FRAMES", 1 << 12, raising=False)
    cmu = data_dir / "cmu_iclone" / "001_01.bvh.gz"
    bandai = data_dir / "bandai_namco" / "dataset-2" / "dataset-2_walk_active_001.bvh.gz"
    for path, kw in [(cmu, {}), (cmu, {"fold_root": False}), (bandai, {})]:
        m = read_bvh(path, **kw)
        rots, root, offsets = _all_at_once(path, **kw)
        assert m.rotations.dtype == np.float32 and m.root_positions.dtype == np.float32
        assert m.rotations.tobytes() == rots.tobytes(), (path.name, kw)
        assert m.root_positions.tobytes() == root.tobytes(), (path.name, kw)
        assert m.skeleton.offsets.tobytes() == offsets.tobytes(), (path.name, kw)


def test_a_wide_take_holds_no_float64_transforms_of_every_frame(data_dir, monkeypatch):
    """Memory after the values are parsed: all of the take's float64 transforms (56 bytes a
    joint-frame) were made at once, then cast; now a block at a time (made small here so a
    real take spans many). What is allocated after parsing stays under half of them."""
    import tracemalloc

    from pipeline.motion import bvh

    monkeypatch.setattr(bvh, "_BLOCK_JOINT_FRAMES", 1 << 12, raising=False)
    parse = bvh._parse_motion

    def parsed_then_traced(*a):
        out = parse(*a)
        tracemalloc.start()
        return out

    monkeypatch.setattr(bvh, "_parse_motion", parsed_then_traced)
    try:
        m = read_bvh(data_dir / "cmu_iclone" / "001_01.bvh.gz")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    T, J = m.rotations.shape[:2]
    assert peak < 0.5 * 56 * T * (J + 1), (peak, 56 * T * (J + 1))
