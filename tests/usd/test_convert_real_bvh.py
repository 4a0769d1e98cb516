"""`tween convert` on BVH written by other tools: CMU's 31-joint rig (zero-length bones),
Rigify and Mixamo names, names with spaces, '/' and Latin-1 bytes, any channel order,
24-120 fps; and one-line refusals (exit 2, nothing written) for bad files and options."""

from __future__ import annotations

import gzip
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pipeline.cli import main
from pipeline.usd.convert import SOURCE_NAMES_ATTR

TWEEN = Path(sys.executable).with_name("tween")
SKEL = "/World/Character/Skel"


def bvh_bytes(joints, frames, frame_time, encoding="utf-8") -> bytes:
    """BVH text for ``joints`` = [(name, parent index, offset, channels)] in file order
    (parents first, children in order) and ``frames`` (T, channels)."""
    kids = {j: [k for k, jt in enumerate(joints) if jt[1] == j] for j in range(len(joints))}
    out = ["HIERARCHY"]

    def emit(j, depth):
        name, parent, off, ch = joints[j]
        pad = "\t" * depth
        out.append(f"{pad}{'ROOT' if parent < 0 else 'JOINT'} {name}")
        out.append(pad + "{")
        out.append(f"{pad}\tOFFSET {off[0]:.6f} {off[1]:.6f} {off[2]:.6f}")
        out.append(f"{pad}\tCHANNELS {len(ch)} {' '.join(ch)}")
        for k in kids[j]:
            emit(k, depth + 1)
        if not kids[j]:
            out.extend([pad + "\tEnd Site", pad + "\t{", pad + "\t\tOFFSET 0.0 1.0 0.0", pad + "\t}"])
        out.append(pad + "}")

    emit(0, 0)
    out += ["MOTION", f"Frames: {len(frames)}", f"Frame Time: {frame_time}"]
    out += [" ".join(f"{v:.6f}" for v in row) for row in frames]
    return ("\r\n".join(out) + "\r\n").encode(encoding)


def rot(order):
    return [f"{a}rotation" for a in order]


def pos(order="XYZ"):
    return [f"{a}position" for a in order]


def rig(spec, root_channels, channels):
    """[(name, parent name, offset)] → joints with channels, in the file's (depth-first) order."""
    order: list[int] = []

    def visit(k):
        order.append(k)
        for c, (_, p, _) in enumerate(spec):
            if p == spec[k][0]:
                visit(c)

    visit(0)
    names = [spec[k][0] for k in order]
    return [
        (n, names.index(p) if p else -1, o, root_channels if not p else channels)
        for n, p, o in (spec[k] for k in order)
    ]


# CMU's 31-joint rig as in the Edinburgh locomotion data: LHipJoint, RHipJoint, LowerBack,
# Neck, the shoulders, finger bases and thumbs have OFFSET 0 0 0 (zero-length bones).
CMU31 = [
    ("Hips", None, (0, 0, 0)), ("LHipJoint", "Hips", (0, 0, 0)),
    ("LeftUpLeg", "LHipJoint", (1.36, -1.79, 0.84)), ("LeftLeg", "LeftUpLeg", (2.45, -6.73, 0)),
    ("LeftFoot", "LeftLeg", (2.56, -7.04, 0)), ("LeftToeBase", "LeftFoot", (0.16, -0.43, 2.32)),
    ("RHipJoint", "Hips", (0, 0, 0)), ("RightUpLeg", "RHipJoint", (-1.31, -1.79, 0.84)),
    ("RightLeg", "RightUpLeg", (-2.54, -6.98, 0)), ("RightFoot", "RightLeg", (-2.57, -7.06, 0)),
    ("RightToeBase", "RightFoot", (-0.17, -0.47, 2.36)),
    ("LowerBack", "Hips", (0, 0, 0)), ("Spine", "LowerBack", (0.03, 2.06, -0.01)),
    ("Spine1", "Spine", (0.01, 2.06, -0.06)), ("Neck", "Spine1", (0, 0, 0)),
    ("Neck1", "Neck", (0.01, 1.57, 0.15)), ("Head", "Neck1", (0.03, 1.56, -0.1)),
    ("LeftShoulder", "Spine1", (0, 0, 0)), ("LeftArm", "LeftShoulder", (3.36, 1.2, 0)),
    ("LeftForeArm", "LeftArm", (4.98, 0, 0)), ("LeftHand", "LeftForeArm", (3.48, 0, 0)),
    ("LeftFingerBase", "LeftHand", (0, 0, 0)), ("LeftHandIndex1", "LeftFingerBase", (0.72, 0, 0)),
    ("LThumb", "LeftHand", (0, 0, 0)),
    ("RightShoulder", "Spine1", (0, 0, 0)), ("RightArm", "RightShoulder", (-3.14, 1.2, 0)),
    ("RightForeArm", "RightArm", (-5.24, 0, 0)), ("RightHand", "RightForeArm", (-3.44, 0, 0)),
    ("RightFingerBase", "RightHand", (0, 0, 0)), ("RightHandIndex1", "RightFingerBase", (-0.62, 0, 0)),
    ("RThumb", "RightHand", (0, 0, 0)),
]  # fmt: skip

RIGIFY = [("spine", None, (0, 95, 0))]
RIGIFY += [(f"spine.{k:03d}", "spine" if k == 1 else f"spine.{k - 1:03d}", (0, 11, 0)) for k in range(1, 7)]
for s, x in (("L", 1), ("R", -1)):
    RIGIFY += [
        (f"shoulder.{s}", "spine.003", (x * 2, 8, 0)), (f"upper_arm.{s}", f"shoulder.{s}", (x * 16, 0, 0)),
        (f"forearm.{s}", f"upper_arm.{s}", (x * 28, 0, 0)), (f"hand.{s}", f"forearm.{s}", (x * 25, 0, 0)),
        (f"thigh.{s}", "spine", (x * 9, -3, 0)), (f"shin.{s}", f"thigh.{s}", (0, -44, 0)),
        (f"foot.{s}", f"shin.{s}", (0, -42, 0)), (f"toe.{s}", f"foot.{s}", (0, -7, 12)),
    ]  # fmt: skip

# Mixamo's prefix, spaces, '/', Latin-1 accents, a leading digit and two joints whose
# names only differ in characters USD does not allow.
ODD = [
    ("mixamorig:Hips", None, (0, 0, 0)), ("Spine Lower", "mixamorig:Hips", (0, 10, 0)),
    ("Épaule/Gauche", "Spine Lower", (5, 10, 0)), ("Épaule/Droite", "Spine Lower", (-5, 10, 0)),
    ("Hand.L", "Épaule/Gauche", (20, 0, 0)), ("Hand L", "Épaule/Droite", (-20, 0, 0)),
    ("01 Tête", "Spine Lower", (0, 15, 0)),
]  # fmt: skip


def angles_for(joints, T, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(-60, 60, (T, len(joints), 3))


def frames_for(joints, angles, root_pos):
    """The channel values: positions (root: root_pos, below: the OFFSET) and ``angles``
    (T, J, 3) in each joint's own rotation order."""
    cols = []
    for j, (_, parent, off, ch) in enumerate(joints):
        for c in ch:
            if c.endswith("position"):
                a = "XYZ".index(c[0])
                cols.append(root_pos[:, a] if parent < 0 else np.full(len(root_pos), off[a]))
            else:
                order = "".join(x[0] for x in ch if x.endswith("rotation"))
                cols.append(angles[:, j, order.index(c[0])])
    return np.stack(cols, axis=1)


def write_clip(tmp_path, name, joints, T, frame_time, seed=0, encoding="utf-8"):
    angles = angles_for(joints, T, seed)
    root = np.stack([np.linspace(0, 50, T), np.full(T, 90.0), np.linspace(0, 20, T)], axis=1)
    p = tmp_path / name
    p.write_bytes(bvh_bytes(joints, frames_for(joints, angles, root), frame_time, encoding))
    return p, angles, root


def tween(monkeypatch, capsys, *args) -> tuple[int, str, str]:
    """Runs the `tween` entry point in this process: (exit status, stdout, stderr)."""
    monkeypatch.setattr(sys, "argv", ["tween", *map(str, args)])
    with pytest.raises(SystemExit) as e:
        main()
    captured = capsys.readouterr()
    return e.value.code or 0, captured.out, captured.err


def check_shot(out: Path, joints, angles, root, fps):
    """The shot opens, its joint tokens are valid paths of a valid topology, the names as
    written are kept, and rotations and translations equal the BVH's."""
    from pxr import Sdf, Usd, UsdGeom, UsdSkel

    stage = Usd.Stage.Open(str(out))
    assert stage.GetTimeCodesPerSecond() == fps and stage.GetFramesPerSecond() == fps
    sk = UsdSkel.Skeleton(stage.GetPrimAtPath(SKEL))
    tokens = list(sk.GetJointsAttr().Get())
    assert len(tokens) == len(joints) == len(set(tokens))
    for t in tokens:
        assert Sdf.Path.IsValidPathString(t)[0], t
        for element in t.split("/"):
            assert Sdf.Path.IsValidIdentifier(element) and Sdf.Path.IsValidPathString(element)[0], t
    ok, why = UsdSkel.Topology(sk.GetJointsAttr().Get()).Validate()
    assert ok, why
    for t, (_, parent, _, _) in zip(tokens, joints, strict=True):  # the hierarchy is the file's
        assert (t.rpartition("/")[0] or None) == (tokens[parent] if parent >= 0 else None)
    names = [n for n, *_ in joints]
    source = sk.GetPrim().GetAttribute(SOURCE_NAMES_ATTR)
    if any(not Sdf.Path.IsValidIdentifier(n) for n in names):
        assert list(source.Get()) == names
    anim = UsdSkel.Animation(stage.GetPrimAtPath(SKEL + "/Anim"))
    assert list(anim.GetJointsAttr().Get()) == tokens
    start = stage.GetStartTimeCode()
    assert stage.GetEndTimeCode() == start + len(angles) - 1
    for k in range(len(angles)):
        q = np.array([[*r.imaginary, r.real] for r in anim.GetRotationsAttr().Get(start + k)])
        for j, (_, _, _, ch) in enumerate(joints):
            order = "".join(c[0] for c in ch if c.endswith("rotation"))
            want = Rotation.from_euler(order, angles[k, j], degrees=True)
            got = Rotation.from_quat(q[j])
            assert (want.inv() * got).magnitude() < 1e-5, (k, joints[j][0])
        tr = np.array(anim.GetTranslationsAttr().Get(start + k))
        np.testing.assert_allclose(tr[0], root[k], atol=1e-4)
        np.testing.assert_allclose(tr[1:], [o for _, _, o, _ in joints[1:]], atol=1e-5)
    for attr in (sk.GetRestTransformsAttr(), sk.GetBindTransformsAttr()):
        assert np.isfinite(np.array(attr.Get())).all()
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Character/Mannequin"))
    pts = np.array(mesh.GetPointsAttr().Get())
    assert len(pts) and np.isfinite(pts).all()
    # The mannequin skins at every frame without NaNs.
    cache = UsdSkel.Cache()
    skel_root = UsdSkel.Root(stage.GetPrimAtPath("/World/Character"))
    cache.Populate(skel_root, Usd.PrimDefaultPredicate)
    skq = cache.GetSkelQuery(sk)
    sq = cache.GetSkinningQuery(mesh.GetPrim())
    for t in (start, start + len(angles) - 1):
        p = mesh.GetPointsAttr().Get(t)
        assert sq.ComputeSkinnedPoints(skq.ComputeSkinningTransforms(t), p, t)
        assert np.isfinite(np.array(p)).all()
    return stage, tokens


def test_cmu31_zero_length_bones_120fps(tmp_path, monkeypatch, capsys):
    joints = rig(CMU31, pos("XYZ") + rot("ZYX"), rot("ZYX"))
    src, angles, root = write_clip(tmp_path, "cmu31.bvh", joints, 12, 0.008333)
    out = tmp_path / "cmu31.usda"
    code, stdout, err = tween(monkeypatch, capsys, "convert", src, out)
    assert code == 0, err
    assert stdout.strip() == str(out)
    stage, tokens = check_shot(out, joints, angles, root, 120)
    assert "Hips/LHipJoint/LeftUpLeg" in tokens
    assert not stage.GetPrimAtPath(SKEL).GetAttribute(SOURCE_NAMES_ATTR)  # every name was valid


def test_rigify_names_xyz_6_channels_everywhere_24fps(tmp_path, monkeypatch, capsys):
    joints = rig(RIGIFY, pos() + rot("XYZ"), pos() + rot("XYZ"))  # Blender: 6 channels per bone
    src, angles, root = write_clip(tmp_path, "rigify.bvh.gz", joints, 9, 0.041667, seed=1)
    src.write_bytes(gzip.compress(src.read_bytes()))
    out = tmp_path / "rigify.usdc"
    code, _, err = tween(monkeypatch, capsys, "convert", src, out, "--keys-every", "1")
    assert code == 0, err
    stage, tokens = check_shot(out, joints, angles, root, 24)
    leaf = [t.rsplit("/", 1)[-1] for t in tokens]
    assert leaf[:7] == ["spine", "spine_001", "spine_002", "spine_003", "spine_004", "spine_005", "spine_006"]
    assert {"thigh_L", "thigh_R", "upper_arm_L", "upper_arm_R", "toe_L", "toe_R"} <= set(leaf)
    assert "spine/spine_001/spine_002/spine_003/shoulder_L/upper_arm_L" in tokens


def test_odd_names_latin1_yxz_30fps(tmp_path, monkeypatch, capsys):
    joints = rig(ODD, pos("ZXY") + rot("YXZ"), rot("YXZ"))
    src, angles, root = write_clip(tmp_path, "odd.bvh", joints, 6, 0.0333333, seed=2, encoding="latin-1")
    assert b"\xc9paule/Gauche" in src.read_bytes()  # not UTF-8
    out = tmp_path / "odd.usda"
    code, _, err = tween(monkeypatch, capsys, "convert", src, out)
    assert code == 0, err
    stage, tokens = check_shot(out, joints, angles, root, 30)
    leaf = [t.rsplit("/", 1)[-1] for t in tokens]
    assert leaf == [
        "mixamorig_Hips",
        "Spine_Lower",
        "Epaule_Gauche",
        "Hand_L",
        "Epaule_Droite",
        "Hand_L_2",  # "Hand L" also makes Hand_L: the later one gets a number
        "_01_Tete",
    ]
    names = list(stage.GetPrimAtPath(SKEL).GetAttribute(SOURCE_NAMES_ATTR).Get())
    assert names[2] == "Épaule/Gauche" and names[6] == "01 Tête"


def test_joint_names_are_deterministic_unique_and_keep_valid_names():
    from pipeline.usd.convert import usd_joint_names

    names = ["Hips", "thigh.L", "thigh_L", "x", "x", "x_2", "日本", "a..b", "Hips"]
    got = usd_joint_names(names)
    assert got == ["Hips", "thigh_L_2", "thigh_L", "x", "x_3", "x_2", "joint_6", "a_b", "Hips_2"]
    assert got == usd_joint_names(list(names)) and len(set(got)) == len(got)
    assert usd_joint_names(["Hips", "Spine", "CC_Base_Hip"]) == ["Hips", "Spine", "CC_Base_Hip"]


def test_rest_pose_falls_back_when_reference_pose_is_not_finite(tmp_path, monkeypatch):
    """Whatever the reference pose does with zero-length bones, the rest pose is finite."""
    import pipeline.adapt.retarget as retarget
    from pipeline.motion.bvh import read_bvh
    from pipeline.usd.convert import rest_pose

    joints = rig(CMU31, pos() + rot("ZYX"), rot("ZYX"))
    src, _, _ = write_clip(tmp_path, "cmu31.bvh", joints, 3, 0.008333)
    m = read_bvh(src)
    r, t = rest_pose(m)
    assert np.isfinite(r).all() and np.isfinite(t).all()
    monkeypatch.setattr(retarget, "reference_pose", lambda roles, g, p: np.full((21, 4), np.nan))
    r, t = rest_pose(m)
    np.testing.assert_array_equal(r, m.rotations[0])  # the first frame


# ---- refusals: one line on stderr naming the file or option, exit 2, nothing written ----

GOOD = rig([("Hips", None, (0, 0, 0)), ("Spine", "Hips", (0, 10, 0))], pos() + rot("ZXY"), rot("ZXY"))


def good_clip(tmp_path, T=10):
    return write_clip(tmp_path, "good.bvh", GOOD, T, 0.0333333)[0]


def assert_refused(tmp_path, monkeypatch, capsys, args, starts):
    out_dir = tmp_path / "out"
    out_dir.mkdir(exist_ok=True)
    before = sorted(tmp_path.rglob("*"))
    code, stdout, err = tween(monkeypatch, capsys, "convert", *args)
    assert code == 2, (args, err)
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"tween: error: {starts}"), (args, err)
    assert stdout == ""
    assert sorted(tmp_path.rglob("*")) == before  # no shot, no temporary file
    return lines[0]


BAD_FILES = {
    "missing": None,
    "empty.bvh": b"",
    "garbage.bvh": bytes(range(256)) * 4,
    "truncated.bvh": b"HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n",
    "corrupt.bvh.gz": b"not gzip at all",
    "wrotation.bvh": "Wrotation Xrotation Yrotation\n\tJOINT",
    "twice.bvh": "Zrotation Zrotation Yrotation\n\tJOINT",
    "nan.bvh": "frame nan",
    "huge.bvh": "frame 1e39",
    "one_frame.bvh": "one frame",
}


@pytest.mark.parametrize("case", list(BAD_FILES))
def test_bad_file_is_one_line_exit_2_nothing_written(tmp_path, monkeypatch, capsys, case):
    src = tmp_path / case
    what = BAD_FILES[case]
    if case == "missing":
        pass
    elif isinstance(what, bytes):
        src.write_bytes(what)
    else:
        text = good_clip(tmp_path).read_text()
        if what.startswith("frame "):
            lines = text.splitlines()
            v = what.split()[1]
            lines[-1] = " ".join([v] + lines[-1].split()[1:])
            text = "\n".join(lines) + "\n"
        elif what == "one frame":
            text = text.replace("Frames: 10", "Frames: 1")
        else:
            text = text.replace("Zrotation Xrotation Yrotation\n\tJOINT", what, 1)
        src.write_text(text)
        (tmp_path / "good.bvh").unlink()
    assert_refused(tmp_path, monkeypatch, capsys, [src, tmp_path / "out" / "shot.usda"], str(src))


def test_input_folder_is_refused(tmp_path, monkeypatch, capsys):
    folder = tmp_path / "clip.bvh"
    folder.mkdir()
    line = assert_refused(tmp_path, monkeypatch, capsys, [folder, tmp_path / "out" / "s.usda"], str(folder))
    assert "folder" in line


@pytest.mark.parametrize(
    "option,value",
    [
        ("--frames", "x"), ("--frames", "5"), ("--frames", "-1-3"), ("--frames", "3-3"),
        ("--frames", "4-2"), ("--frames", "0-10"), ("--frames", "0-1.5"),
        ("--fps", "0"), ("--fps", "-24"), ("--fps", "nan"), ("--fps", "inf"), ("--fps", "1001"),
        ("--fps", "abc"), ("--fps", "0.001"),
        ("--start", "inf"), ("--start", "nan"), ("--start", "abc"),
        ("--keys-every", "0"), ("--keys-every", "-1"), ("--keys-every", "2.5"), ("--keys-every", "x"),
        ("--up", "x"), ("--name", "my char"), ("--name", "1abc"),
    ],
)  # fmt: skip
def test_bad_option_is_one_line_naming_it(tmp_path, monkeypatch, capsys, option, value):
    src = good_clip(tmp_path)
    out = tmp_path / "out" / "shot.usda"
    assert_refused(tmp_path, monkeypatch, capsys, [src, out, f"{option}={value}"], f"{option} ")


@pytest.mark.parametrize("target", ["out", "out/shot.txt", "nowhere/shot.usda"])
def test_bad_output_path_is_one_line_naming_it(tmp_path, monkeypatch, capsys, target):
    src = good_clip(tmp_path)
    (tmp_path / "out").mkdir()
    out = tmp_path / target
    assert_refused(tmp_path, monkeypatch, capsys, [src, out], str(out))


def test_write_failure_leaves_no_partial_shot(tmp_path, monkeypatch, capsys):
    import pipeline.usd.convert as convert

    def broken(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(convert, "_mannequin", broken)
    src = good_clip(tmp_path)
    out = tmp_path / "out" / "shot.usda"
    line = assert_refused(tmp_path, monkeypatch, capsys, [src, out], str(out))
    assert "No space left" in line


def test_installed_command_prints_one_line():
    """The real `tween` entry point, as a user runs it."""
    res = subprocess.run(
        [str(TWEEN), "convert", "/nonexistent/clip.bvh", "/tmp/never.usda", "--frames", "0-5"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == 2
    assert res.stderr.splitlines() == ["tween: error: /nonexistent/clip.bvh: file not found"]
    assert not Path("/tmp/never.usda").exists()
