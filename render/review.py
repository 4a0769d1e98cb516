"""``render_review``: review media for one filled shot (or take): turntable MP4, frames, contact sheet."""

from __future__ import annotations

import os
import queue
import re
import shutil
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pipeline.errors import TweenError
from pipeline.outputs import file_above, missing_folders, remove_created
from pipeline.progress import interval
from pipeline.usd.files import clean_dead_temps, owner_tag
from render.camera import FRAMINGS, VIEWS, Camera, follow_path
from render.geometry import Geometry
from render.gl import RenderError
from render.output import Movie, contact_sheet, frame_metadata, png_rows, thumbnail, write_frame, write_png
from render.overlays import BurnIn
from render.raster import BLOCKING_CLAY, CLAY, Renderer
from render.scene import (
    SUMMARY_FACTS,
    Shot,
    evaluate,
    frame_times,
    open_shot,
    shot_label,
    shot_timing,
    take_names,
)
from render.timeline import folder_lock, take_track, update_timeline

MAX_GHOSTS = 8
#: The body paths and key marks are drawn this many seconds either side of the current frame:
#: a long shot's whole path is a scribble, and its every frame drawn on every frame made the
#: time per frame grow with the shot. A shot of a minute or less shows all of it.
TRAIL_S = 30.0
CONTACT_FRAMES = 12
QUEUE_FRAMES = 4  # rendered frames waiting for the writer thread at most (bounded memory)
FRAME_THREADS = 2  # threads writing numbered frames (PNG/EXR encoding lets go of the GIL)


class FrameWriter:
    """The second half of the render loop on its own thread, so the GL loop never waits on it.

    ``buffer()`` hands out one of ``depth + 2`` frame buffers (waiting while all are in use:
    the render loop is at most ``depth`` frames ahead); ``put(i, buf)`` queues the rendered
    frame; the thread calls ``handle(i, buf, save)`` in frame order and recycles the buffer.
    ``save(fn, *args)`` runs ``fn`` on one of ``frame_threads`` more threads (numbered frames),
    at most ``2 * frame_threads`` queued. An error on any thread is raised by the next call in
    the render loop, or by ``close()``, which waits for everything.
    """

    def __init__(self, shape, handle, depth: int = QUEUE_FRAMES, frame_threads: int = 0):

        self.handle, self.error, self.cancelled = handle, None, False
        self.free: queue.Queue = queue.Queue()
        for _ in range(depth + 2):
            self.free.put(np.empty(shape, np.uint8))
        self.todo: queue.Queue = queue.Queue(maxsize=depth)
        self.pool = ThreadPoolExecutor(frame_threads, "review-frames") if frame_threads else None
        self.slots = threading.BoundedSemaphore(2 * frame_threads) if frame_threads else None
        self.jobs: list = []
        self.thread = threading.Thread(target=self._run, name="review-writer", daemon=True)
        self.thread.start()

    def _save(self, fn, *args):
        if self.pool is None:
            return fn(*args)
        self.slots.acquire()
        job = self.pool.submit(fn, *args)
        job.add_done_callback(lambda _: self.slots.release())
        self.jobs.append(job)
        for done in [j for j in self.jobs if j.done()]:
            self.jobs.remove(done)
            done.result()  # raises a writer's error here, on the writer thread
        return None

    def _run(self):
        while True:
            item = self.todo.get()
            if item is None:
                break
            i, buf = item
            try:
                if self.error is None and not self.cancelled:
                    self.handle(i, buf, self._save)
            except BaseException as e:  # handed to the render loop
                self.error = e
            finally:
                self.free.put(buf)

    def _check(self):
        if self.error is not None:
            raise self.error

    def buffer(self) -> np.ndarray:

        while True:
            self._check()
            try:
                return self.free.get(timeout=0.5)
            except queue.Empty:
                if not self.thread.is_alive():
                    raise RenderError("the review's writer thread stopped") from None

    def put(self, i: int, buf: np.ndarray) -> None:
        self._check()
        self.todo.put((i, buf))

    def close(self) -> None:
        self.todo.put(None)
        self.thread.join()
        try:
            self._check()
            for job in self.jobs:
                job.result()
        finally:
            if self.pool is not None:
                self.pool.shutdown(wait=True)

    def abort(self) -> None:
        self.cancelled = True
        self.todo.put(None)
        self.thread.join(timeout=30)
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)


def _frame_bounds(geom_lists) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sampled frame indices, per-frame min (S, 3), per-frame max (S, 3)) over every geometry."""
    b = [g.frame_bounds() for gl in geom_lists for g in gl if g.n_points and g.n_frames]
    idx = b[0][0]
    lo = np.min([x[1] for x in b], axis=0).astype(np.float64)
    hi = np.max([x[2] for x in b], axis=0).astype(np.float64)
    return idx, lo, hi


def _bounds(geom_lists) -> tuple[np.ndarray, np.ndarray]:
    _, lo, hi = _frame_bounds(geom_lists)
    return lo.min(0), hi.max(0)


def camera_modes(camera: str, framing: str | None = None) -> tuple[str, str]:
    """(view, framing) from ``camera`` (turntable | front | side, or follow | fixed: the
    turntable so framed) and ``framing`` (follow | fixed; default follow)."""
    if camera in FRAMINGS:
        if framing is not None and framing != camera:
            raise RenderError(f"camera {camera!r} and framing {framing!r} disagree")
        camera, framing = "turntable", camera
    framing = framing or "follow"
    if camera not in VIEWS:
        raise RenderError(f"camera must be one of {', '.join(VIEWS + FRAMINGS)}, not {camera!r}")
    if framing not in FRAMINGS:
        raise RenderError(f"framing must be follow or fixed, not {framing!r}")
    return camera, framing


@dataclass
class Plan:
    """What a review draws and how it is framed, decided once before the first frame."""

    shot: Shot
    panels: list  # [geometries] per panel (blocking, fill when side by side)
    roots: list  # each character's body joint path (T, 3)
    lo: np.ndarray  # the whole motion's box
    hi: np.ndarray
    camera: Camera
    burn: BurnIn
    size: tuple[int, int]
    framing: str


def plan_review(
    stage_path: str,
    take: int | None = None,
    size=(960, 540),
    side_by_side: bool = False,
    camera: str = "turntable",
    turns: float = 1.0,
    frame_range: tuple[float, float] | None = None,
    framing: str | None = None,
    shot: Shot | None = None,
) -> Plan:
    """Opens the shot, evaluates what is drawn and frames the camera (see ``render.camera``)."""
    view, framing = camera_modes(camera, framing)
    w, h = (int(v) for v in size)
    shot = shot or open_shot(stage_path, take, frame_range)
    T = len(shot.times)
    geoms, roots = evaluate(shot, shot.times)
    panels = [evaluate(shot, shot.held_times())[0], geoms] if side_by_side else [geoms]
    idx, flo, fhi = _frame_bounds(panels)
    lo, hi = flo.min(0), fhi.max(0)
    labels = ["BLOCKING (stepped keys)", "FILLED"] if side_by_side else None
    burn = BurnIn((w, h), shot.name, shot.facts, shot.fps, labels)
    covered = burn.band * (4 if side_by_side else 2)  # the bands (and panel labels) are symmetric-ish
    aspect, safe = (w / len(panels)) / h, 1.0 - covered / h
    if framing == "fixed":
        cam = Camera(lo, hi, aspect, T, view, turns, safe=safe)
    else:
        follow = follow_path(np.mean([np.asarray(r, np.float64) for r in roots], axis=0), shot.fps)
        ground = follow[idx] * [1.0, 0.0, 1.0]  # the character's box around the followed point
        cam = Camera(lo, hi, aspect, T, view, turns, safe=safe, follow=follow,
                     local_min=(flo - ground).min(0), local_max=(fhi - ground).max(0))  # fmt: skip
    return Plan(shot, panels, roots, lo, hi, cam, burn, (w, h), framing)


def _materialise(g: Geometry) -> Geometry:
    frames = [g.frame(i) for i in range(g.n_frames)]
    pts = np.stack([f[0] for f in frames])
    nrm = np.stack([f[1] for f in frames]) if g.smooth else None
    return Geometry.from_arrays(g.tris, pts, nrm)


def _ghost_geometry(shot: Shot) -> list[Geometry] | None:
    """The key poses drawn as ghosts: at most MAX_GHOSTS of the keys in the shot's range,
    spread over them; None when there are none."""
    if not len(shot.key_times):
        return None
    kt = shot.key_times[(shot.key_times >= shot.times[0] - 1e-6) & (shot.key_times <= shot.times[-1] + 1e-6)]
    if not len(kt):
        return None
    kt = kt[np.unique(np.linspace(0, len(kt) - 1, min(MAX_GHOSTS, len(kt))).round().astype(int))]
    # few frames, drawn every frame: materialise them once
    return [_materialise(g) for g in evaluate(shot, kt)[0]]


def _frame_finisher(
    plan: Plan, movie: Movie, tmp: Path, stem: str, exr: bool, write_frames: bool, thumbs, frames
):
    """What the writer thread does with each rendered frame, in frame order: burn-in, MP4,
    thumbnail (into ``thumbs``), numbered frame (its name into ``frames``)."""
    shot, burn = plan.shot, plan.burn
    w = plan.size[0]
    T = len(shot.times)
    is_key = shot.is_key()
    n_thumbs = min(CONTACT_FRAMES, T)
    thumb_at = set(np.linspace(0, T - 1, n_thumbs).round().astype(int).tolist())
    ext = "exr" if exr else "png"
    colorspace = "lin_rec709" if exr else "sRGB"
    tcs = shot.timecodes()

    def finish_frame(i: int, img: np.ndarray, save) -> None:
        """On the writer thread, in frame order: burn-in, MP4, thumbnail, numbered frame."""
        fno = int(shot.frames[i])
        burn.apply(img, fno, bool(is_key[i]), tcs[i])  # RGBA: the whole-pixel path
        movie.add(img)
        if i in thumb_at:
            thumbs.append((thumbnail(img, max(1, w // 480)), f"{fno}" + (" KEY" if is_key[i] else ""),
                           bool(is_key[i])))  # fmt: skip
        if write_frames:
            name = f"{stem}.{fno:04d}.{ext}"
            meta = frame_metadata(shot.name, shot.take, shot.facts, fno, colorspace)
            if exr:
                save(write_frame, str(tmp / name), np.ascontiguousarray(img[..., :3]), meta, True)
            else:  # the rows copied out of the recycled buffer here, deflated on a frame thread
                save(write_png, str(tmp / name), png_rows(img), meta)
            frames.append(name)

    return finish_frame


def _render_frames(
    plan: Plan, renderer: Renderer, sets, ghost_set, tmp: Path, stem: str, side_by_side: bool, exr: bool,
    write_frames: bool, progress: bool,
) -> tuple[list, list[str]]:  # fmt: skip
    """Renders every frame of the shot into ``tmp``: the MP4 (encoded as the frames come) and,
    with ``write_frames``, the numbered frames. Returns the contact sheet's thumbnails and the
    numbered frames' file names."""
    shot, cam = plan.shot, plan.camera
    w, h = plan.size
    is_key = shot.is_key()
    colors = [BLOCKING_CLAY, CLAY] if side_by_side else [CLAY]
    rate = shot.timing.rate if shot.timing is not None else shot.fps
    movie = Movie(
        str(tmp / f"{stem}.mp4"),
        (w, h),
        rate,
        comment=f"{shot.name} {shot.take or ''} {_summary(shot.facts)}",
    )
    try:
        thumbs, frames = [], []
        it = range(len(shot.times))
        if progress:
            it = tqdm(it, desc=f"review {shot.name}", unit="f", file=sys.stderr, mininterval=interval())
        finish_frame = _frame_finisher(plan, movie, tmp, stem, exr, write_frames, thumbs, frames)
        writer = FrameWriter((h, w, 4), finish_frame, frame_threads=FRAME_THREADS if write_frames else 0)
        try:
            for i in it:
                buf = writer.buffer()
                renderer.render(
                    i, [cam] * len(plan.panels), sets, colors, bool(is_key[i]), ghost_set, out=buf
                )
                writer.put(i, buf)
            # Inside: Ctrl-C while close() waits for the writer thread closed the movie under
            # the thread still encoding the last frames into it (a segmentation fault).
            writer.close()
        except BaseException:
            writer.abort()  # the thread stopped before the movie is closed
            raise
        movie.close()
    except BaseException:
        movie.abort()
        raise
    return thumbs, frames


@contextmanager
def _scratch(out: Path, job: str):
    """A scratch folder in ``out`` (made if missing) for a review's media, removed when done;
    on failure ``out`` too is removed if this made it, and the folders above it this made
    (the default ``review/<shot>``: an interrupted first review left an empty ``review``)."""
    created = missing_folders(out)
    if not created and not out.is_dir():
        raise TweenError(f"{out}: is a file, not a folder for the review's media")
    tmp = None
    try:  # from the mkdir on: an interrupt lands just after a call that made a folder
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as e:  # said "Not a directory" where a folder above it is a file
            above = file_above(out)
            why = f"{above} is a file, not a folder" if above is not None else e.strerror
            raise TweenError(f"{out}: cannot make the folder for the review's media: {why}") from None
        clean_dead_temps(out, quiet=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".tween-review-{job}.{owner_tag()}.", suffix=".tmp", dir=out))
        yield tmp
    except BaseException:
        if created:
            shutil.rmtree(out, ignore_errors=True)
            remove_created(created)
        raise
    finally:  # on failure too: the scratch goes before the error leaves
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


def _write_sheet_and_timeline(
    plan: Plan, stage_path: str, out: Path, tmp: Path, stem: str, thumbs, key_idx, side_by_side: bool,
    exr: bool, write_frames: bool,
) -> Path:  # fmt: skip
    """Writes the contact sheet and this take's track of the shot's timeline in ``tmp``, then
    moves every medium of ``tmp`` into ``out`` under the folder's lock. Returns the timeline."""
    shot, cam = plan.shot, plan.camera
    ext = "exr" if exr else "png"
    rate = shot.timing.rate if shot.timing is not None else shot.fps
    title = f"{shot.name}  {shot.take or ''}  {shot.facts.get('model', 'no model')}  {len(shot.times)} frames @ {shot.fps:g} fps"
    contact_sheet(thumbs, str(tmp / f"{stem}_contact.png"), title)
    timeline = out / f"{shot.name.replace(' ', '_')}.otio"
    track = take_track(
        f"{stem}.mp4", rate, shot.frames, [int(shot.frames[i]) for i in key_idx], shot.take, shot.facts,
        {"shot": shot.name, "stage": str(stage_path), "contact_sheet": f"{stem}_contact.png",
         "frames": f"{stem}.####.{ext}" if write_frames else None, "camera": cam.mode,
         "framing": plan.framing, "side_by_side": bool(side_by_side)},
    )  # fmt: skip
    with folder_lock(out):
        update_timeline(timeline, tmp / timeline.name, shot.name, track, shot.facts,
                        keep=lambda url: bool(url) and (out / url).exists())  # fmt: skip
        _move_in(tmp, out, _stale_frames(out, tmp, stem, ext, write_frames))
    return timeline


def _move_in(tmp: Path, out: Path, stale: Sequence[str] = ()) -> None:
    """Moves every medium of ``tmp`` into ``out``, all or none: a folder where a medium goes is
    refused before anything moves, and a move that fails puts back what the others replaced
    (the earlier render's media, kept aside in ``tmp``) so no timeline names a movie not there.
    The files of ``out`` named in ``stale`` (an earlier review's frames no new one replaces)
    are set aside with them: gone with ``tmp`` once all moved in, else put back."""
    files = sorted(f for f in tmp.iterdir() if f.is_file())
    for f in files:
        dest = out / f.name
        if dest.is_dir() and not dest.is_symlink():
            raise TweenError(f"{dest}: is a folder; the review's {f.name} goes there (move it away)")
    aside = tmp / ".replaced"
    aside.mkdir()
    done: list[tuple[Path, Path | None]] = []
    try:
        # Each recorded before it moves: an interrupt between the two still puts it back.
        for name in stale:
            done.append((out / name, aside / name))
            (out / name).replace(aside / name)
        for f in files:
            dest = out / f.name
            old = aside / f.name if dest.exists() or dest.is_symlink() else None
            done.append((dest, old))
            if old is not None:
                dest.replace(old)
            f.replace(dest)
    except BaseException:
        for dest, old in reversed(done):
            if old is None:
                dest.unlink(missing_ok=True)
            elif old.exists() or old.is_symlink():
                old.replace(dest)
        raise


def _frame_names(names, stem: str) -> list[str]:
    """The numbered frames of the take ``stem`` among ``names``, PNG or EXR: exactly the names a
    review writes (``sh010_take1.1001.png``, ``sh010_take1.-001.exr``; ``_frame_finisher``)."""
    pattern = re.compile(rf"^{re.escape(stem)}\.(-?\d+)\.(?:png|exr)$")
    return sorted(n for n in names if (m := pattern.match(n)) and f"{int(m[1]):04d}" == m[1])


def _stale_frames(out: Path, tmp: Path, stem: str, ext: str, write_frames: bool) -> list[str]:
    """The numbered frames of an earlier review of this take in ``out`` that the media in
    ``tmp`` do not replace by name: frames outside the new range, or in the other format. They
    go with the review they belong to, so a narrower ``--frames`` or an ``--exr`` leaves no old
    frame beside the new. Empty when ``out`` holds no earlier review of the take as
    ``earlier_media`` finds one (its MP4, contact sheet, or with ``write_frames`` a frame in
    ``ext``): what ``tween review`` refuses without --force, so without it nothing goes."""
    names = set(os.listdir(out))
    # A folder named like a medium is not the review's (earlier_media skips it too).
    files = {
        n
        for n in [f"{stem}.mp4", f"{stem}_contact.png", *_frame_names(names, stem)]
        if n in names and ((out / n).is_symlink() or not (out / n).is_dir())
    }
    frames = _frame_names(files, stem)
    earlier = f"{stem}.mp4" in files or f"{stem}_contact.png" in files
    if not (earlier or (write_frames and any(n.endswith(f".{ext}") for n in frames))):
        return []
    new = set(os.listdir(tmp))
    return [n for n in frames if n not in new]


def media_stem(shot_name: str, take: str | None) -> str:
    """The review media's names start with this: ``sh010_v001_take1`` (``.mp4``, ``_contact.png``,
    ``.1001.png``)."""
    return shot_name.replace(" ", "_") + (f"_{take}" if take else "")


def earlier_media(stage_path: str, out_dir: str, takes: list[int | None], exr: bool = False,
                  write_frames: bool = True) -> Path | None:  # fmt: skip
    """The first file in ``out_dir`` a review of ``takes`` would replace (a take's MP4, then its
    contact sheet, then with ``write_frames`` a numbered frame of it), or None. The stage is
    opened (for its takes' names) only when a file there is named like the shot's media."""
    out = Path(out_dir)
    try:
        names = set(os.listdir(out))
    except OSError:  # not there yet (or not a folder: rendering says so)
        return None
    label = shot_label(stage_path)
    if not any(n.startswith(media_stem(label, None)) for n in names):
        return None
    ext = "exr" if exr else "png"
    for take in take_names(stage_path, takes):
        stem = media_stem(label, take)
        frame = re.compile(rf"^{re.escape(stem)}\.-?\d+\.{ext}$")
        frames = sorted(n for n in names if write_frames and frame.match(n))
        for name in [f"{stem}.mp4", f"{stem}_contact.png", *frames]:
            # A folder there is not replaced, with --force either: moving the media in names it.
            if name in names and ((out / name).is_symlink() or not (out / name).is_dir()):
                return out / name
    return None


def render_review(
    stage_path: str,
    out_dir: str,
    take: int | None = None,
    size=(960, 540),
    side_by_side: bool = False,
    exr: bool = False,
    camera: str = "turntable",
    turns: float = 1.0,
    ghosts: bool = False,
    write_frames: bool = True,
    frame_range: tuple[float, float] | None = None,
    progress: bool = False,
    framing: str | None = None,
    job: str = "local",
) -> dict:
    """Renders every animated skeleton of ``stage_path`` into ``out_dir``.

    ``camera``: turntable | front | side (or follow | fixed: the turntable so framed);
    ``framing``: follow (default: the camera follows the character) | fixed (framed once on
    the whole motion). Also writes/updates ``<shot>.otio`` (``render.timeline``): this take's
    track replaces its previous one, the other takes' are kept.

    Returns {"mp4", "contact_sheet", "timeline", "frames": [...], "frame_numbers", "timecodes",
    "key_frames", "fps", "size", "take", "model", "camera", "framing", "timings"}; ``fps`` is the
    playback rate (``scene.shot_timing``). Nothing is left in ``out_dir`` if rendering fails.

    The media are rendered in a hidden scratch folder of ``out_dir``,
    ``.tween-review-<job>.<pid>@<host>.<random>.tmp`` (``job``: the farm job's id), then moved
    into place; the scratch of a writer that died on this host is removed first, and a farm
    worker that takes a job over removes the job's own (``workers.cleanup.clean_scratch``).
    """
    # Long because of its 14 options and the docstring of what it returns; the body is the
    # stages in order (plan, ghosts, render the frames, sheet and timeline, result).
    t0 = time.perf_counter()
    plan = plan_review(stage_path, take, size, side_by_side, camera, turns, frame_range, framing)
    shot = plan.shot
    w, h = plan.size
    T = len(shot.times)
    key_idx = np.nonzero(shot.is_key())[0]
    ghost_geoms = _ghost_geometry(shot) if ghosts else None
    t_scene = time.perf_counter() - t0

    out = Path(out_dir)
    stem = media_stem(shot.name, shot.take)
    with _scratch(out, job) as tmp:
        renderer = Renderer((w, h), panels=len(plan.panels))
        sets = []
        try:
            renderer.set_stage(plan.lo, plan.hi, float(plan.lo[1]), plan.roots, key_idx, TRAIL_S * shot.fps)
            sets = [renderer.mesh_set(g) for g in plan.panels]
            ghost_set = renderer.mesh_set(ghost_geoms) if ghost_geoms else None
            thumbs, frames = _render_frames(
                plan, renderer, sets, ghost_set, tmp, stem, side_by_side, exr, write_frames, progress
            )
            timeline = _write_sheet_and_timeline(
                plan, stage_path, out, tmp, stem, thumbs, key_idx, side_by_side, exr, write_frames
            )
        finally:
            for s in sets:
                s.release()
            renderer.release()
    total = time.perf_counter() - t0
    return {
        "mp4": str(out / f"{stem}.mp4"),
        "contact_sheet": str(out / f"{stem}_contact.png"),
        "timeline": str(timeline),
        "frames": [str(out / f) for f in frames],
        "frame_numbers": [int(f) for f in shot.frames],
        "timecodes": shot.timecodes(),
        "key_frames": [int(shot.frames[i]) for i in key_idx],
        "fps": shot.fps,
        "size": (w, h),
        "take": shot.take,
        "model": shot.facts.get("model"),  # what filled it (None: no fill in the stage)
        "camera": plan.camera.mode,
        "framing": plan.framing,
        "timings": {"scene_s": round(t_scene, 3), "total_s": round(total, 3), "fps": round(T / total, 1)},
    }


def review_frames(stage_path: str) -> int:
    """How many frames a review of ``stage_path`` renders per take (the stage's authored time
    code range, else its SkelAnimations' samples, at the playback rate), read without
    evaluating anything: what the farm sizes the render's time limits by."""
    from pxr import Usd

    stage = Usd.Stage.Open(str(stage_path), load=Usd.Stage.LoadNone)
    if stage is None:
        return 1
    if stage.HasAuthoredTimeCodeRange():
        start, end = stage.GetStartTimeCode(), stage.GetEndTimeCode()
    else:
        ts = [
            t
            for prim in stage.Traverse()
            if prim.GetTypeName() == "SkelAnimation"
            for attr in prim.GetAttributes()
            for t in attr.GetTimeSamples()
        ]
        start, end = (min(ts), max(ts)) if ts else (0.0, 0.0)
    return len(frame_times(start, end, shot_timing(stage))[0])


def _summary(facts: dict) -> dict:
    """The facts of the fill as a whole, not its per-gap arrays (which grow with the shot)."""
    return {k: facts[k] for k in SUMMARY_FACTS if k in facts}


__all__ = ["render_review", "RenderError"]
