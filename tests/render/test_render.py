"""Review turntables rendered from real clips and real USD assets, checked as a reviewer would:
frame count and size, a visible moving character, KEY markers exactly on key frames, an MP4
with the right frame count and rate, and metadata that reads back."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from render_fixtures import converted_review, start_frames

from pipeline.errors import ShotError
from render.gl import RenderError
from render.overlays import KEY_RGB, BurnIn
from render.review import render_review
from render.scene import open_shot

SIZE = (320, 180)
KEY = np.array([round(c * 255) for c in KEY_RGB])


def _read(path) -> np.ndarray:
    buf = oiio.ImageBuf(str(path))
    assert not buf.has_error, buf.geterror()
    return buf.get_pixels(oiio.UINT8)


def _clay(img: np.ndarray, band: int) -> np.ndarray:
    """Mask of the character's warm clay pixels (the ground and background are neutral grey)."""
    rgb = img[band:-band, 4:-4, :3].astype(int)  # inside the bands and the KEY border
    return (rgb[..., 0] - rgb[..., 2] > 25) & (rgb[..., 0] > 60) & (rgb[..., 1] > rgb[..., 2])


def _blue(img: np.ndarray, band: int) -> np.ndarray:
    rgb = img[band:-band, 4:-4, :3].astype(int)
    return (rgb[..., 2] - rgb[..., 0] > 20) & (rgb[..., 2] > 70)


@pytest.fixture(scope="module")
def review(tmp_path_factory, bandai_clip):
    """A real clip converted and filled (2 takes, keys every 10 frames), rendered at take 1."""
    work = tmp_path_factory.mktemp("render")
    stage, keys = converted_review(bandai_clip, work, frames=60, key_step=10, takes=2)
    out = render_review(stage, str(work / "out"), take=1, size=SIZE, camera="front")
    return {"stage": stage, "keys": keys, "out": out, "work": work}


def test_frames_count_size_and_numbers(review):
    out = review["out"]
    assert len(out["frames"]) == 60
    assert out["frame_numbers"] == list(range(1001, 1061))
    for f in out["frames"][::20]:
        spec = oiio.ImageInput.open(f).spec()
        assert (spec.width, spec.height, spec.nchannels) == (*SIZE, 3)
    assert [Path(f).name for f in out["frames"][:2]] == [
        "sh010_v001_take1.1001.png",
        "sh010_v001_take1.1002.png",
    ]


def test_character_visible_and_moving(review):
    band = BurnIn(SIZE, "x", {}, 30).band
    imgs = [_read(f) for f in review["out"]["frames"][::15]]
    masks = [_clay(im, band) for im in imgs]
    for m in masks:
        # the character stands out from the background and is framed (not a speck, not the whole frame)
        assert 0.005 < m.mean() < 0.5, m.mean()
    cx = np.array([np.nonzero(m)[1].mean() for m in masks])
    # the front camera follows the walk (default framing): the character stays in the middle
    assert np.all(np.abs(cx - (SIZE[0] - 8) / 2) < 0.1 * SIZE[0]), cx
    # consecutive frames differ where the character is
    a, b = imgs[0].astype(int), imgs[1].astype(int)
    assert np.abs(a - b).sum(-1)[band:-band].astype(bool).mean() > 0.002


def test_key_marker_exactly_on_key_frames(review):
    burn = BurnIn(SIZE, "x", {}, 30)
    x, y, kw, kh = burn.key_rect
    marked = []
    for f, n in zip(review["out"]["frames"], review["out"]["frame_numbers"], strict=True):
        img = _read(f).astype(int)
        badge = img[y : y + kh, x : x + kw].reshape(-1, 3)
        orange = (np.abs(badge - KEY).sum(-1) < 60).mean() > 0.5
        border = np.abs(img[0, SIZE[0] // 3] - KEY).sum() < 30
        assert orange == border, n
        if orange:
            marked.append(n)
    assert marked == review["keys"] == review["out"]["key_frames"]
    assert marked == [1001, 1011, 1021, 1031, 1041, 1051, 1060]


def test_mp4_frames_rate_and_format(review):
    import av
    from av.video.frame import PictureType

    with av.open(review["out"]["mp4"]) as box:
        st = box.streams.video[0]
        assert st.codec_context.name == "h264"
        assert st.codec_context.pix_fmt == "yuv420p"
        assert (st.codec_context.width, st.codec_context.height) == SIZE
        assert st.average_rate == 30
        # Main profile with B-frames (render/output.py's Movie, docs/render.md).
        assert st.codec_context.profile == "Main"
        types = [PictureType(f.pict_type) for f in box.decode(st)]
    assert len(types) == 60 and PictureType.B in types


def test_metadata_reads_back(review):
    spec = oiio.ImageInput.open(review["out"]["frames"][10]).spec()
    assert spec.getattribute("tween:shot") == "sh010 v001"
    assert spec.getattribute("tween:take") == "take1"
    assert spec.getattribute("tween:model") == "interpolation"
    assert int(spec.getattribute("tween:frame")) == 1011
    assert spec.getattribute("oiio:ColorSpace") in ("sRGB", "srgb_rec709_scene")
    sheet = oiio.ImageInput.open(review["out"]["contact_sheet"]).spec()
    assert sheet.width > SIZE[0] and sheet.height > SIZE[1]


def test_takes_differ(review):
    """Take 0 and take 1 are different fills; each gets its own media."""
    out0 = render_review(review["stage"], str(review["work"] / "t0"), take=0, size=SIZE, camera="front",
                         frame_range=(1005, 1005))  # fmt: skip
    f1 = [f for f in review["out"]["frames"] if f.endswith(".1005.png")][0]
    assert Path(out0["frames"][0]).name == "sh010_v001_take0.1005.png"
    assert np.abs(_read(out0["frames"][0]).astype(int) - _read(f1)).max() > 0


def test_side_by_side_blocking_vs_fill(review, tmp_path):
    out = render_review(review["stage"], str(tmp_path), take=1, size=SIZE, side_by_side=True, camera="front",
                        frame_range=(1011, 1016), ghosts=True, framing="fixed")  # fmt: skip
    band = BurnIn(SIZE, "x", {}, 30).band
    key, mid = _read(out["frames"][0]), _read(out["frames"][5])
    half = SIZE[0] // 2
    for img in (key, mid):
        assert _blue(img, band)[:, :half].mean() > 0.003  # blocking panel: the stepped keys
        assert _clay(img, band)[:, half:].mean() > 0.003  # fill panel
    # between keys the stepped blocking still holds key 1011's pose: its panel barely changes
    d_left = np.abs(key[:, :half].astype(int) - mid[:, :half]).sum(-1)[2 * band : -band].astype(bool).mean()
    d_right = np.abs(key[:, half:].astype(int) - mid[:, half:]).sum(-1)[2 * band : -band].astype(bool).mean()
    assert d_right > 2 * d_left


def test_exr_frames(review, tmp_path):
    out = render_review(review["stage"], str(tmp_path), take=1, size=SIZE, exr=True, frame_range=(1001, 1002))
    assert [Path(f).suffix for f in out["frames"]] == [".exr", ".exr"]
    spec = oiio.ImageInput.open(out["frames"][0]).spec()
    assert spec.format == oiio.HALF
    assert spec.getattribute("tween:shot") == "sh010 v001"
    assert spec.getattribute("oiio:ColorSpace").startswith("lin_rec709")  # OIIO may add "_scene"


def test_plain_shot_keys_are_rotation_samples(tmp_path, bandai_clip):
    from pipeline.motion.bvh import read_bvh
    from pipeline.usd.convert import write_shot

    shot = write_shot(read_bvh(bandai_clip).slice(0, 25), tmp_path / "sh020.usda", keys_every=8)
    out = render_review(shot, str(tmp_path / "out"), size=SIZE, write_frames=False)
    assert out["key_frames"] == [1001, 1009, 1017, 1025]
    assert out["take"] is None


def test_z_up_shot_stands_up(tmp_path, bandai_clip):
    from pipeline.motion.bvh import read_bvh
    from pipeline.usd.convert import write_shot

    shot = write_shot(read_bvh(bandai_clip).slice(0, 3), tmp_path / "sh030.usda", up_axis="Z")
    out = render_review(shot, str(tmp_path / "out"), size=SIZE, camera="front")
    band = BurnIn(SIZE, "x", {}, 30).band
    ys, xs = np.nonzero(_clay(_read(out["frames"][0]), band))
    assert np.ptp(ys) > 1.5 * np.ptp(xs)  # a standing person seen from the front is taller than wide


@pytest.mark.parametrize(
    "asset, frames",
    [
        ("RiggedFigure/RiggedFigure.usdz", None),
        ("ElephantWithMonochord/SoC-ElephantWithMonochord.usdc", (1, 24)),
    ],
)
def test_real_usd_assets(data_dir, tmp_path, asset, frames):
    """Skinned meshes of real assets (Z_UP transforms, metersPerUnit 0.01) are framed and upright."""
    out = render_review(str(data_dir / "usd_assets" / asset), str(tmp_path), size=SIZE, frame_range=frames,
                        camera="front")  # fmt: skip
    band = BurnIn(SIZE, "x", {}, 30).band
    img = _read(out["frames"][len(out["frames"]) // 2])
    m = _clay(img, band)
    assert 0.02 < m.mean() < 0.6, m.mean()
    ys, xs = np.nonzero(m)
    assert ys.max() > m.shape[0] * 0.5 and ys.min() < m.shape[0] * 0.5  # centred vertically
    assert out["key_frames"], "keys from the authored rotation samples"


def test_bad_input(tmp_path, review):
    with pytest.raises(ShotError, match="file not found"):
        render_review(str(tmp_path / "missing.usda"), str(tmp_path / "o1"))
    with pytest.raises(ShotError, match="no take 7"):
        render_review(review["stage"], str(tmp_path / "o2"), take=7)
    with pytest.raises(RenderError, match="even"):
        render_review(review["stage"], str(tmp_path / "o3"), size=(321, 180))
    assert (
        not (tmp_path / "o1").exists() and not (tmp_path / "o2").exists() and not (tmp_path / "o3").exists()
    )
    bad = tmp_path / "bad.usda"
    bad.write_text("#usda 1.0\n(\n garbage")
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "review", str(bad), "-o", str(tmp_path / "o4")],
                       capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and str(bad) in r.stderr, r.stderr
    assert not (tmp_path / "o4").exists()


def test_missing_egl_is_one_clear_line(monkeypatch):
    import moderngl

    import render.gl as gl

    def no_egl(**kw):
        raise Exception("libEGL.so: cannot open shared object file")

    monkeypatch.setattr(gl, "_CTX", None)
    monkeypatch.setattr(moderngl, "create_standalone_context", no_egl)
    with pytest.raises(RenderError, match="apt-get install -y libegl1") as e:
        gl.context()
    assert "\n" not in str(e.value)


def test_cli_review(review, tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "pipeline.cli", "review", review["stage"], "--take", "0", "--size", "160x90",
         "--no-frames", "--frames", "1001:1010", "-o", str(tmp_path)],
        capture_output=True, text=True,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    import json

    summary = json.loads(r.stdout)
    assert summary["frame_count"] == 10 and Path(summary["mp4"]).is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "sh010_v001.otio",
        "sh010_v001_take0.mp4",
        "sh010_v001_take0_contact.png",
    ]


def test_frames_past_the_shot_are_said_and_cut_to_it(review, capsys):
    shot = open_shot(review["stage"], frame_range=(990, 1003))
    assert shot.times[0] == 1001 and shot.times[-1] == 1003
    err = capsys.readouterr().err
    assert (
        err
        == f"tween: {review['stage']}: --frames 990:1003 reaches past the shot's 1001-1060; rendering 1001-1003\n"
    )
    open_shot(review["stage"], frame_range=(1001, 1003))  # within the shot: nothing said
    assert capsys.readouterr().err == ""


def test_start_frames_helper():
    assert start_frames() == 1001


def test_cli_all_takes(review, tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "pipeline.cli", "review", review["stage"], "--all-takes", "--size", "160x90",
         "--no-frames", "--frames", "1001:1003", "-o", str(tmp_path)],
        capture_output=True, text=True,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    names = sorted(p.name for p in tmp_path.iterdir() if p.suffix == ".mp4")
    assert names == ["sh010_v001_take0.mp4", "sh010_v001_take1.mp4"]


@pytest.mark.parametrize("fps, tcps", [(100000, 100000), (240000, 24)])
def test_a_playback_rate_no_review_plays_is_refused_up_front(tmp_path, fps, tcps):
    """At 100,000 frames a second the camera's smoothing (half a second of frames wide) took
    minutes on 97 frames, deaf to SIGTERM; 240,000 over 24 time codes made 960,001 frames."""
    from pxr import Usd

    from render.scene import MAX_RATE

    shot = tmp_path / "sh.usda"
    shot.write_bytes(Path(__file__).resolve().parents[2].joinpath("examples/sh010_walk.usda").read_bytes())
    stage = Usd.Stage.Open(str(shot))
    stage.SetFramesPerSecond(fps)
    stage.SetTimeCodesPerSecond(tcps)
    stage.Save()
    with pytest.raises(
        ShotError, match=f"plays at {fps} frames a second .*; a review plays at most {MAX_RATE}"
    ):
        open_shot(str(shot))
    with pytest.raises(ShotError, match="a review plays at most"):
        render_review(str(shot), str(tmp_path / "o"))
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("stage", ["_render_frames", "clean_dead_temps"])
def test_an_interrupted_first_review_leaves_no_folder_it_made(tmp_path, monkeypatch, stage):
    """Ctrl-C or SIGTERM during the first `tween review` of a shot took back its media folder,
    ``review/<shot>``, but left the ``review`` folder made with it, empty, where none was; and
    one landing just after the folder was made (before the scratch) left both."""
    import render.review as review_module

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(review_module, stage, interrupted)
    shot = Path(__file__).resolve().parents[2] / "examples" / "sh010_walk.usda"
    (tmp_path / "kept").mkdir()
    for out in (tmp_path / "review" / "sh010_walk", tmp_path / "kept" / "a" / "b"):
        with pytest.raises(KeyboardInterrupt):
            render_review(str(shot), str(out), size=(160, 90), frame_range=(1001, 1002))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept"] and not any((tmp_path / "kept").iterdir())


def test_an_interrupted_review_of_every_take_keeps_none_of_them(review, tmp_path):
    """Ctrl-C while `tween review --all-takes` rendered its second take left the first take's
    movie, frames, contact sheet and timeline: the same command then refused ("--out holds an
    earlier review of this take; give --force"). Interrupted here as the second take starts."""
    hook = (
        "import sys\n"
        "import render.cli as cli\n"
        "real, calls = cli.render_review, []\n"
        "def render_review(*a, **k):\n"
        "    calls.append(1)\n"
        "    if len(calls) == 2:\n"
        "        raise KeyboardInterrupt\n"
        "    return real(*a, **k)\n"
        "cli.render_review = render_review\n"
        "from pipeline.cli import main\n"
        "main(sys.argv[1:])\n"
    )
    kept = tmp_path / "kept"
    kept.mkdir()
    (kept / "sh010_v001.otio").write_text("an earlier timeline")  # its media removed since
    (kept / "notes.txt").write_text("mine")
    for out in (tmp_path / "new" / "sh010", kept):
        args = ["review", review["stage"], "--all-takes", "--size", "160x90", "--frames", "1001:1002",
                "-o", str(out)]  # fmt: skip
        r = subprocess.run([sys.executable, "-c", hook, *args], capture_output=True, text=True)
        assert r.returncode == 130 and r.stderr.splitlines()[-1] == "tween: interrupted", r.stderr
    assert not (tmp_path / "new").exists()
    assert sorted(p.name for p in kept.iterdir()) == ["notes.txt", "sh010_v001.otio"]
    assert (kept / "sh010_v001.otio").read_text() == "an earlier timeline"
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", *args], capture_output=True, text=True)
    assert r.returncode == 0 and len(list(kept.glob("*.mp4"))) == 2, r.stderr


def test_an_interrupt_as_the_last_frames_are_encoded_stops_the_writer_before_the_movie(tmp_path, monkeypatch):
    """Ctrl-C while the review waited for its writer thread to encode the last frames closed
    the movie under that thread: a segmentation fault (status -11; about 1 in 20 Ctrl-Cs in the
    last quarter second of `tween review --all-takes`), leaving the scratch and the first
    take's media. Here the signal lands as close() waits, the thread slowed to be still busy."""
    import time

    import render.review as review_module
    from render.output import Movie

    writers, alive = [], []
    real_add, real_abort = Movie.add, Movie.abort

    def slow_add(self, rgb):
        time.sleep(0.2)
        real_add(self, rgb)

    def close_interrupted(self):
        writers.append(self)
        self.todo.put(None)
        raise KeyboardInterrupt

    def abort(self):
        alive.append(writers[0].thread.is_alive())
        writers[0].thread.join()  # so that the old order fails here, not in a crash
        real_abort(self)

    monkeypatch.setattr(Movie, "add", slow_add)
    monkeypatch.setattr(Movie, "abort", abort)
    monkeypatch.setattr(review_module.FrameWriter, "close", close_interrupted)
    shot = Path(__file__).resolve().parents[2] / "examples" / "sh010_walk.usda"
    with pytest.raises(KeyboardInterrupt):
        render_review(str(shot), str(tmp_path / "o"), size=(160, 90), frame_range=(1001, 1003))
    assert alive == [False] and not (tmp_path / "o").exists()
