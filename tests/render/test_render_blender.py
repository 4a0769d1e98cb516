"""Reviews of shots as Blender 5 exports them (``tests/blender_fixtures.py``): played at their
timeCodesPerSecond with every time code rendered, time codes burnt in at that rate, and the
ground path and KEY ring on the hips, not on the static root bone at the origin."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from blender_fixtures import FRAMES, TCPS, build_blender_shot, hips_path, joint_paths

from render.review import render_review
from render.scene import evaluate, open_shot


@pytest.fixture(scope="module")
def blender_shot(tmp_path_factory) -> dict:
    return build_blender_shot(tmp_path_factory.mktemp("blender") / "blender.usda")


@pytest.mark.parametrize("time_range", [True, False])
def test_frame_count_equals_time_code_count(tmp_path, time_range):
    from pxr import Usd, UsdGeom, UsdSkel

    shot = build_blender_shot(tmp_path / "bl.usda", time_range=time_range)
    # the fixture is what Blender writes
    stage = Usd.Stage.Open(shot["path"])
    layer = stage.GetRootLayer()
    assert layer.HasTimeCodesPerSecond() and not layer.HasFramesPerSecond()
    assert stage.GetTimeCodesPerSecond() == pytest.approx(TCPS) and stage.GetFramesPerSecond() == 24
    assert stage.HasAuthoredTimeCodeRange() == time_range
    assert UsdGeom.GetStageUpAxis(stage) == "Z" and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    skel = UsdSkel.Skeleton(stage.GetPrimAtPath("/root/Armature/Armature"))
    assert list(skel.GetJointsAttr().Get())[:3] == ["root", "root/Hips", "root/Hips/Spine"]
    rest = np.array(skel.GetRestTransformsAttr().Get())
    assert np.allclose(rest[:, :3, :3], np.eye(3)) and np.allclose(rest[:, 3, 1:3], 0)
    anim = UsdSkel.Animation(stage.GetPrimAtPath("/root/Armature/Armature/Anim"))
    assert anim.GetTranslationsAttr().GetTimeSamples() == list(range(1, FRAMES + 1))

    s = open_shot(shot["path"])
    assert len(s.times) == FRAMES  # not 209 (24 fps over 30 time codes a second)
    assert np.array_equal(s.times, shot["times"])
    assert s.frames.tolist() == list(range(1, FRAMES + 1))
    assert s.fps == 30


def test_timing_frame_numbers_and_timecodes(blender_shot):
    from pxr import Usd

    from render.scene import Timing, frame_times, shot_timing, timecodes

    timing = shot_timing(Usd.Stage.Open(blender_shot["path"]))
    assert timing.tcps == pytest.approx(TCPS) and timing.fps == pytest.approx(TCPS)
    assert timing.rate == Fraction(30) and timing.step == 1.0
    times, frames = frame_times(1, FRAMES, timing)
    assert frames.tolist() == list(range(1, FRAMES + 1)) and np.array_equal(times, frames)
    tcs = timecodes(times, timing)
    assert tcs[:2] == ["00:00:00:01", "00:00:00:02"]
    assert tcs[29:31] == ["00:00:01:00", "00:00:01:01"]
    assert tcs[-1] == "00:00:08:21"  # time code 261 at 30 fps: 8 s and 21 frames
    assert len(set(tcs)) == FRAMES  # nothing doubled or dropped
    assert open_shot(blender_shot["path"]).timecodes() == tcs

    def timing_of(tcps, fps=None):
        st = Usd.Stage.CreateInMemory()
        st.SetTimeCodesPerSecond(tcps)
        if fps is not None:
            st.SetFramesPerSecond(fps)
        return shot_timing(st)

    # both authored: framesPerSecond as before; a near-integer step neither drops nor doubles
    t = timing_of(TCPS, 30)
    assert t.rate == 30 and t.step == 1.0 and len(frame_times(1, FRAMES, t)[0]) == FRAMES
    t = timing_of(24, 24)
    assert (t.rate, t.step) == (24, 1.0)
    t = timing_of(48, 24)  # two time codes a frame: frame numbers are time codes, time codes in seconds
    times, frames = frame_times(1001, 1011, t)
    assert frames.tolist() == [1001, 1003, 1005, 1007, 1009, 1011]
    assert timecodes(times, t)[:2] == ["00:00:20:21", "00:00:20:22"]  # 1001 / 48 s = 500.5 frames
    assert timing_of(29.97).rate == Fraction(30000, 1001)
    assert timing_of(25.0, 25.0) == Timing(25.0, 25.0, Fraction(25), 1.0)


def test_followed_joint_is_the_hips(blender_shot):
    shot = open_shot(blender_shot["path"])
    _, paths = evaluate(shot, shot.times)
    path = paths[0].astype(np.float64)
    hips = hips_path()
    # Z up -> Y up: (x, y, z) -> (x, z, -y)
    assert np.allclose(path, np.stack([hips[:, 0], hips[:, 2], -hips[:, 1]], 1), atol=1e-4)
    assert np.ptp(path[:, 0]) > 3.5 and np.ptp(path[:, 2]) > 1.0  # metres, not zero
    assert shot.characters[0].body == 1  # root/Hips, not the static root bone


def test_body_joint_without_hips_names(tmp_path):
    """Bones named Bone, Bone_001, ... (Blender's Bone.001 as a valid token): the first joint
    below the static root that moves."""
    names = ["Bone"] + [f"Bone_{k:03d}" for k in range(1, len(joint_paths()))]
    shot = open_shot(build_blender_shot(tmp_path / "bones.usda", names=names)["path"])
    assert np.ptp(evaluate(shot, shot.times[::20])[1][0][:, 0]) > 3.0
    assert shot.characters[0].body == 1


def test_body_joint_rules():
    from render.scene import body_joint

    T = 5
    walk = np.linspace(0, 2, T)[:, None] * [1.0, 0, 0]
    # joint 0 is the hips (the example shot): kept
    parents = [-1, 0, 1, 0, 3]
    pos = np.zeros((T, 5, 3)) + walk[:, None]
    assert body_joint(pos, parents, ["Hips", "Spine", "Head", "UpperLeg_L", "Foot_L"]) == 0
    assert body_joint(pos, parents, ["a", "b", "c", "d", "e"]) == 0
    # a static root bone above a moving body, whatever the names
    parents = [-1, 0, 1, 2, 1, 4, 0]
    pos = np.zeros((T, 7, 3))
    pos[:, 1:6] += walk[:, None]
    assert body_joint(pos, parents, ["root", "pelvis", "spine", "head", "thigh", "foot", "ik"]) == 1
    assert body_joint(pos, parents, ["a", "b", "c", "d", "e", "f", "g"]) == 1
    # a leg's "Left_Hip" is never the body; nothing moving: the root
    assert body_joint(pos, parents, ["root", "b", "c", "d", "Left_Hip", "f", "g"]) == 1
    assert body_joint(np.zeros((T, 7, 3)), parents, ["a", "b", "c", "d", "e", "f", "g"]) == 0


def test_static_root_bone_is_not_drawn(blender_shot):
    """No capsule from the root bone at the origin to the hips (metres away) lies on the ground."""
    shot = open_shot(blender_shot["path"], frame_range=(1, 1))
    geoms, _ = evaluate(shot, shot.times)
    pts = geoms[0].frame(0)[0]
    assert np.linalg.norm(pts[:, [0, 2]], axis=1).min() > 1.0  # the hips start 1.5 m from the origin


def _read(path) -> np.ndarray:
    buf = oiio.ImageBuf(str(path))
    assert not buf.has_error, buf.geterror()
    return buf.get_pixels(oiio.UINT8).astype(int)


def test_blender_shot_renders_end_to_end(blender_shot, tmp_path):
    import av

    out = render_review(blender_shot["path"], str(tmp_path), size=(160, 90), frame_range=(100, 103))
    assert out["frame_numbers"] == [100, 101, 102, 103]
    assert out["timecodes"] == ["00:00:03:10", "00:00:03:11", "00:00:03:12", "00:00:03:13"]
    assert [Path(f).name for f in out["frames"]] == [f"blender.{n:04d}.png" for n in range(100, 104)]
    assert out["fps"] == 30
    with av.open(out["mp4"]) as box:
        st = box.streams.video[0]
        assert st.average_rate == 30
        assert sum(1 for _ in box.decode(st)) == 4
    assert int(oiio.ImageInput.open(out["frames"][2]).spec().getattribute("tween:frame")) == 102


def test_key_ring_is_at_the_character(blender_shot, tmp_path):
    """Front camera, a key frame (a plain shot: every sample is a key): the red-orange KEY ring
    on the ground is under the character, not at the origin."""
    out = render_review(blender_shot["path"], str(tmp_path), size=(320, 180), camera="front",
                        frame_range=(200, 200))  # fmt: skip
    assert out["key_frames"] == [200]
    img = _read(out["frames"][0])[20:-20, 6:-6]  # inside the burn-in bands and the KEY border
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    ring = (r > 150) & (g < 0.5 * r) & (b < 0.3 * r)
    clay = (r - b > 25) & (g > 0.7 * r) & (g > b) & (r > 60)
    assert ring.sum() > 20 and clay.sum() > 50
    ys, xs = np.nonzero(clay)
    head_x = xs[ys <= ys.min() + 3].mean()  # a standing figure's head is above its hips
    ring_x = np.nonzero(ring)[1].mean()
    assert abs(ring_x - head_x) < 0.05 * img.shape[1], (ring_x, head_x)


def test_a_skeleton_outside_any_skelroot_is_reviewed(tmp_path):
    """Blender exports an armature without a mesh as a Skeleton under plain Xforms; the
    review finds it through the fill's own character reader (pipeline.usd.read)."""
    from pxr import Usd, UsdSkel

    shot = build_blender_shot(tmp_path / "armature.usda", frames=12)
    stage = Usd.Stage.Open(str(shot["path"]))
    prim = stage.GetPrimAtPath("/root/Armature")
    prim.SetTypeName("Xform")
    prim.RemoveAPI(UsdSkel.BindingAPI)
    stage.GetRootLayer().Save()
    s = open_shot(str(shot["path"]))
    assert len(s.characters) == 1 and len(s.times) == 12
