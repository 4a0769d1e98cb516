"""The render loop's speed-ups keep what a frame shows (issue 20, item 4).

The characters, trajectory and key marks are drawn multisampled only inside the screen
rectangle they cover (``raster.screen_rect``): drawing the whole frame that way must give the
same pixels. The writer thread (``review.FrameWriter``) hands every frame to its handler in
order, and an error there surfaces once, in the render loop."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from render_fixtures import converted_review

from render import raster
from render.review import FrameWriter, _materialise, plan_review
from render.scene import evaluate

SIZE = (320, 180)


@pytest.fixture(scope="module")
def stage(tmp_path_factory, bandai_clip):
    work = tmp_path_factory.mktemp("speed")
    return converted_review(bandai_clip, work, frames=40, key_step=10, takes=1)[0]


def _frames(plan, frames, ghosts=False, reach=raster.EVERY_FRAME):
    r = raster.Renderer(plan.size, panels=len(plan.panels))
    try:
        is_key = plan.shot.is_key()
        r.set_stage(plan.lo, plan.hi, float(plan.lo[1]), plan.roots, np.nonzero(is_key)[0], reach)
        sets = [r.mesh_set(g) for g in plan.panels]
        gs = None
        if ghosts:
            gs = r.mesh_set([_materialise(g) for g in evaluate(plan.shot, plan.shot.key_times[:3])[0]])
        colors = [raster.BLOCKING_CLAY, raster.CLAY][-len(plan.panels) :]
        cams = [plan.camera] * len(plan.panels)
        return [r.render(i, cams, sets, colors, bool(is_key[i]), gs).copy() for i in frames]
    finally:
        r.release()


@pytest.mark.parametrize("side_by_side", [False, True])
def test_layer_rectangle_changes_no_pixel(stage, monkeypatch, side_by_side):
    plan = plan_review(stage, size=SIZE, side_by_side=side_by_side)
    frames = [0, 10, 17, 39]  # key frames (ring, badge) and in-betweens
    # the rectangle does cut: the character is a small part of the frame
    rect = raster.screen_rect(plan.camera.view_proj(0), (0, 0, *SIZE), [plan.panels[0][0].frame(0)[0]])
    assert rect is not None and rect[2] * rect[3] < 0.5 * SIZE[0] * SIZE[1]
    cut = _frames(plan, frames, ghosts=side_by_side)
    monkeypatch.setattr(raster, "screen_rect", lambda vp, viewport, points, pad=2: tuple(viewport))
    whole = _frames(plan, frames, ghosts=side_by_side)
    for a, b in zip(cut, whole, strict=True):
        assert np.array_equal(a, b)


def test_screen_rect_edges():
    from render.camera import Camera

    cam = Camera(np.array([-0.5, 0.0, -0.5]), np.array([0.5, 1.8, 0.5]), 16 / 9, 10, "front")
    vp, view = cam.view_proj(0), (0, 0, 320, 180)
    x, y, w, h = raster.screen_rect(vp, view, [np.array([[0.0, 0.9, 0.0]])])
    assert 150 < x < 170 and 80 < y < 100 and 4 <= w <= 5 and 4 <= h <= 5  # one point, padded by 2 px
    behind = cam.eye(0) + (cam.eye(0) - cam.target_at(0))  # behind the eye: the whole viewport
    assert raster.screen_rect(vp, view, [np.array([[0.0, 0.9, 0.0], behind])]) == view
    far_left = cam.target_at(0) + np.array([-100.0, 0.0, 0.0])
    assert raster.screen_rect(vp, view, [far_left[None]]) is None
    assert raster.screen_rect(vp, view, [np.zeros((0, 3))]) is None


def test_frame_writer_in_order():
    seen, threads = [], set()

    def handle(i, buf, save):
        seen.append((i, int(buf[0, 0, 0])))
        threads.add(threading.current_thread().name)

    w = FrameWriter((4, 4, 4), handle, depth=2)
    for i in range(50):
        buf = w.buffer()
        buf[...] = i
        w.put(i, buf)
    w.close()
    assert seen == [(i, i) for i in range(50)]
    assert threads == {"review-writer"}


def test_frame_writer_error_surfaces_once():
    handled = []

    def handle(i, buf, save):
        if i == 7:
            raise OSError("disk full")
        handled.append(i)

    w = FrameWriter((4, 4, 4), handle, depth=2)
    with pytest.raises(OSError, match="disk full"):
        for i in range(200):
            w.put(i, w.buffer())
        w.close()
    w.abort()
    assert handled == list(range(7))  # nothing after the failed frame is encoded


def test_frame_writer_save_errors_surface(tmp_path):
    def write(i):
        if i == 3:
            raise ValueError(f"frame {i}: cannot write")

    w = FrameWriter((2, 2, 4), lambda i, buf, save: save(write, i), depth=2, frame_threads=2)
    with pytest.raises(ValueError, match="frame 3"):
        for i in range(10):
            w.put(i, w.buffer())
        w.close()
    w.abort()


def _oiio_png(tmp_path, rgb, level, filt):
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(np.ascontiguousarray(rgb))
    buf.specmod().attribute("png:compressionLevel", level)
    buf.specmod().attribute("png:filter", filt)
    path = str(tmp_path / f"oiio{level}.png")
    assert buf.write(path)
    return path


def test_png_writer_same_pixels_and_metadata(tmp_path, stage):
    """The numbered frames' own PNG writer (stdlib zlib, level 1, unfiltered rows) against
    OIIO's libpng: the same pixels (read back by OIIO and by ffmpeg through PyAV), the same
    text attributes and colour space, and about the size of libpng's level 1."""
    import os

    import av
    import OpenImageIO as oiio

    from render.output import frame_metadata, png_rows, write_frame, write_png

    plan = plan_review(stage, size=SIZE)
    rgba = _frames(plan, [10])[0]
    meta = frame_metadata("sh010 v001", 2, {"model": "interp", "model_hash": "0123abcd"}, 1011, "sRGB")
    meta["tween:note"] = "approved — ✓"  # not Latin-1: iTXt
    path = str(tmp_path / "f.1011.png")
    write_frame(path, rgba, meta)
    b = oiio.ImageBuf(path)
    spec = b.spec()
    assert (spec.width, spec.height, spec.nchannels, spec.format) == (*SIZE, 3, oiio.UINT8)
    assert np.array_equal(b.get_pixels(oiio.UINT8), rgba[..., :3])
    for k, v in meta.items():
        if k != "oiio:ColorSpace":
            assert spec.getattribute(k) == str(v), k
    assert spec.getattribute("oiio:ColorSpace") in ("sRGB", "srgb_rec709_scene")
    with av.open(path) as c:
        assert np.array_equal(next(c.decode(video=0)).to_ndarray(format="rgb24"), rgba[..., :3])
    ref = _oiio_png(tmp_path, rgba[..., :3], 1, 8)
    assert os.path.getsize(path) < 1.15 * os.path.getsize(ref)
    # the rows are a copy: the frame buffer can be reused before they are deflated
    rows = png_rows(rgba)
    rgba[...] = 0
    write_png(str(tmp_path / "g.png"), rows, {})
    assert np.array_equal(
        oiio.ImageBuf(str(tmp_path / "g.png")).get_pixels(oiio.UINT8), b.get_pixels(oiio.UINT8)
    )
    assert not [f for f in os.listdir(tmp_path) if ".tmp" in f]


def test_key_rings_made_once(stage, monkeypatch):
    """Every key frame's ring is in one buffer made by ``set_stage``; a key frame it was not
    told of is still drawn (made on the fly), with the same pixels."""
    plan = plan_review(stage, size=SIZE)
    is_key = plan.shot.is_key()
    keys = np.nonzero(is_key)[0]
    made = []
    discs = raster._discs
    monkeypatch.setattr(raster, "_discs", lambda *a, **k: made.append(1) or discs(*a, **k))
    r = raster.Renderer(plan.size)
    try:
        r.set_stage(plan.lo, plan.hi, float(plan.lo[1]), plan.roots, keys)
        sets = [r.mesh_set(g) for g in plan.panels]
        n = len(made)
        a = r.render(int(keys[1]), [plan.camera], sets, [raster.CLAY], True).copy()
        assert len(made) == n  # nothing made per frame
        r.rings.clear()
        b = r.render(int(keys[1]), [plan.camera], sets, [raster.CLAY], True).copy()
        assert len(made) == n + 1 and np.array_equal(a, b)
        c = r.render(int(keys[1]), [plan.camera], sets, [raster.CLAY], False)
        assert not np.array_equal(a, c)  # the ring is drawn
    finally:
        r.release()


def test_png_rows_packed_copy_same_bytes():
    from render.output import png_rows

    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (37, 50, 4), dtype=np.uint8)
    for view in (img, img[:, 7:41], img[::2], img[..., :3].copy()):
        h, w = view.shape[:2]
        want = np.zeros((h, 3 * w + 1), np.uint8)
        want[:, 1:] = view[..., :3].reshape(h, -1)
        assert np.array_equal(png_rows(view), want)


@pytest.mark.parametrize("panels", [None, ["BLOCKING (stepped keys)", "FILLED"]])
def test_burn_in_rgba_same_colour_as_rgb(panels):
    from render.overlays import BurnIn

    burn = BurnIn((320, 180), "sh010 v001", {"model": "interp", "take": 1, "seed": 3}, 30.0, panels)
    rng = np.random.default_rng(5)
    img = rng.integers(0, 256, (180, 320, 4), dtype=np.uint8)
    for fno, key in ((1001, False), (1010, True)):
        rgb, rgba = img[..., :3].copy(), img.copy()
        burn.apply(rgb, fno, key, "00:00:33:11")
        burn.apply(rgba, fno, key, "00:00:33:11")
        assert np.array_equal(rgba[..., :3], rgb)
        assert np.array_equal(rgba[..., 3], img[..., 3])
        assert not np.array_equal(rgb, img[..., :3])


@pytest.fixture(scope="module")
def long_stage(tmp_path_factory, bandai_clip):
    """A 40-s walk (about 54 m, 1,200 frames), filled: its path and key marks run far out of
    the following camera's view."""
    from render_fixtures import long_walk

    from pipeline.fill.api import FillOptions, fill_shot
    from pipeline.usd.convert import write_shot

    work = tmp_path_factory.mktemp("long")
    shot = write_shot(long_walk(bandai_clip, 1200), work / "walk.usda", keys_every=10)
    return fill_shot(shot, FillOptions(model="interp", out_dir=str(work)))["review"]


def test_overlay_runs_out_of_view_are_not_drawn_and_no_pixel_changes(long_stage, monkeypatch):
    """The path and key marks are drawn by the runs in view (``render.culling``): the time per
    frame grew with the shot's length when every triangle was set up on every frame."""
    from render import culling

    plan = plan_review(long_stage, size=SIZE)
    frames = [0, 400, 777, 1199]  # the first and last frames, a key and an in-between
    shown = []
    visible = culling.Runs.visible
    monkeypatch.setattr(
        culling.Runs, "visible", lambda self, vp: shown.append(visible(self, vp)) or shown[-1]
    )
    cut = _frames(plan, frames)
    assert len(shown) == 2 * len(frames) and all(s.any() for s in shown)
    # past the start, most of the path and its marks lie behind the following camera
    assert all(s.mean() < 0.5 for s in shown[2:])
    monkeypatch.setattr(culling.Runs, "visible", lambda self, vp: np.ones(len(self.first), bool))
    whole = _frames(plan, frames)
    for a, b in zip(cut, whole, strict=True):
        assert np.array_equal(a, b)


def test_overlay_runs_split_into_draw_spans():
    """Adjacent runs in view are one draw call; the last run may be short."""
    from render.culling import RUN, Runs

    data = np.zeros((RUN * 3 + 6, 4), np.float32)
    data[:, 0] = np.arange(len(data))  # each run's box along x
    runs = Runs(data)
    assert runs.count.tolist() == [RUN, RUN, RUN, 6]
    keep = np.array([True, True, False, True])
    assert runs.spans(keep) == [(0, 2 * RUN), (3 * RUN, 6)]
    assert runs.spans(np.zeros(4, bool)) == []
    assert runs.points(keep).shape == (3 * 8, 3)
    # a view that sees x in [-1, 1] (orthographic, identity): the first run only
    assert runs.visible(np.eye(4)).tolist() == [True, False, False, False]


def test_a_long_shot_draws_its_trail_around_the_current_frame(long_stage):
    """The path and key marks are drawn ``reach`` frames either side of the current frame
    (review.TRAIL_S seconds): half-way through a 40-s walk, a 1-s trail leaves out the path in
    view ahead of and behind the character, and a trail longer than the shot draws all of it."""
    from render.review import TRAIL_S

    plan = plan_review(long_stage, size=SIZE)
    assert plan.shot.fps * TRAIL_S >= 30 * 30  # a minute's shot shows all of its path
    whole, trail, longer = (_frames(plan, [600], reach=r)[0] for r in (raster.EVERY_FRAME, 30, 1200))
    assert np.array_equal(whole, longer)
    assert not np.array_equal(whole, trail)
