"""``render_review``: review media for one filled shot (or take): turntable MP4, frames, contact sheet."""

from __future__ import annotations

import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from render.camera import Camera
from render.gl import RenderError
from render.output import Movie, contact_sheet, frame_metadata, thumbnail, write_frame
from render.overlays import BurnIn
from render.raster import BLOCKING_CLAY, CLAY, Renderer
from render.scene import Geometry, evaluate, open_shot

MAX_GHOSTS = 8
CONTACT_FRAMES = 12


def _bounds(geom_lists) -> tuple[np.ndarray, np.ndarray]:
    b = [g.bounds() for gl in geom_lists for g in gl if g.n_points and g.n_frames]
    lo, hi = np.min([x[0] for x in b], axis=0), np.max([x[1] for x in b], axis=0)
    return lo.astype(np.float64), hi.astype(np.float64)


def _materialise(g: Geometry) -> Geometry:
    frames = [g.frame(i) for i in range(g.n_frames)]
    pts = np.stack([f[0] for f in frames])
    nrm = np.stack([f[1] for f in frames]) if g.smooth else None
    return Geometry.from_arrays(g.tris, pts, nrm)


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
) -> dict:
    """Renders every animated skeleton of ``stage_path`` into ``out_dir``.

    Returns {"mp4", "contact_sheet", "frames": [...], "frame_numbers", "timecodes", "key_frames",
    "fps", "size", "take", "timings"}; ``fps`` is the playback rate (``scene.shot_timing``).
    Nothing is left in ``out_dir`` if rendering fails.
    """
    t0 = time.perf_counter()
    w, h = (int(v) for v in size)
    shot = open_shot(stage_path, take, frame_range)
    T = len(shot.times)
    geoms, roots = evaluate(shot, shot.times)
    panels = [evaluate(shot, shot.held_times())[0], geoms] if side_by_side else [geoms]
    lo, hi = _bounds(panels)
    is_key = shot.is_key()
    key_idx = np.nonzero(is_key)[0]
    ghost_geoms = None
    if ghosts and len(shot.key_times):
        kt = shot.key_times[
            (shot.key_times >= shot.times[0] - 1e-6) & (shot.key_times <= shot.times[-1] + 1e-6)
        ]
        if len(kt):
            kt = kt[np.unique(np.linspace(0, len(kt) - 1, min(MAX_GHOSTS, len(kt))).round().astype(int))]
            # few frames, drawn every frame: materialise them once
            ghost_geoms = [_materialise(g) for g in evaluate(shot, kt)[0]]
    t_scene = time.perf_counter() - t0

    out = Path(out_dir)
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    stem = shot.name.replace(" ", "_") + (f"_{shot.take}" if shot.take else "")
    tmp = Path(tempfile.mkdtemp(prefix=".tween-review-", dir=out))
    renderer = movie = None
    try:
        renderer = Renderer((w, h), panels=len(panels))
        renderer.set_stage(lo, hi, float(lo[1]), roots, key_idx)
        sets = [renderer.mesh_set(g) for g in panels]
        colors = [BLOCKING_CLAY, CLAY] if side_by_side else [CLAY]
        ghost_set = renderer.mesh_set(ghost_geoms) if ghost_geoms else None
        labels = ["BLOCKING (stepped keys)", "FILLED"] if side_by_side else None
        burn = BurnIn((w, h), shot.name, shot.facts, shot.fps, labels)
        covered = burn.band * (4 if side_by_side else 2)  # the bands (and panel labels) are symmetric-ish
        cam = Camera(lo, hi, (w / len(panels)) / h, T, camera, turns, safe=1.0 - covered / h)
        rate = shot.timing.rate if shot.timing is not None else shot.fps
        movie = Movie(
            str(tmp / f"{stem}.mp4"), (w, h), rate, comment=f"{shot.name} {shot.take or ''} {shot.facts}"
        )
        n_thumbs = min(CONTACT_FRAMES, T)
        thumb_at = set(np.linspace(0, T - 1, n_thumbs).round().astype(int).tolist())
        thumbs, frames = [], []
        ext = "exr" if exr else "png"
        colorspace = "lin_rec709" if exr else "sRGB"
        it = range(T)
        if progress:
            from tqdm import tqdm

            it = tqdm(it, desc=f"review {shot.name}", unit="f", file=sys.stderr)
        tcs = shot.timecodes()
        for i in it:
            img = renderer.render(i, [cam] * len(panels), sets, colors, bool(is_key[i]), ghost_set)
            fno = int(shot.frames[i])
            burn.apply(img[..., :3], fno, bool(is_key[i]), tcs[i])
            movie.add(img)
            if write_frames:
                name = f"{stem}.{fno:04d}.{ext}"
                write_frame(
                    str(tmp / name),
                    img,
                    frame_metadata(shot.name, shot.take, shot.facts, fno, colorspace),
                    exr,
                )
                frames.append(name)
            if i in thumb_at:
                thumbs.append(
                    (
                        thumbnail(img, max(1, w // 480)),
                        f"{fno}" + (" KEY" if is_key[i] else ""),
                        bool(is_key[i]),
                    )
                )
        movie.close()
        title = f"{shot.name}  {shot.take or ''}  {shot.facts.get('model', 'no model')}  {T} frames @ {shot.fps:g} fps"
        contact_sheet(thumbs, str(tmp / f"{stem}_contact.png"), title)
        for f in tmp.iterdir():
            f.replace(out / f.name)
    except BaseException:
        if movie is not None:
            movie.abort()
        shutil.rmtree(tmp, ignore_errors=True)
        if created:
            shutil.rmtree(out, ignore_errors=True)
        raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        if renderer is not None:
            for s in locals().get("sets", []) or []:
                s.release()
            renderer.release()
    total = time.perf_counter() - t0
    return {
        "mp4": str(out / f"{stem}.mp4"),
        "contact_sheet": str(out / f"{stem}_contact.png"),
        "frames": [str(out / f) for f in frames],
        "frame_numbers": [int(f) for f in shot.frames],
        "timecodes": shot.timecodes(),
        "key_frames": [int(shot.frames[i]) for i in key_idx],
        "fps": shot.fps,
        "size": (w, h),
        "take": shot.take,
        "timings": {"scene_s": round(t_scene, 3), "total_s": round(total, 3), "fps": round(T / total, 1)},
    }


__all__ = ["render_review", "RenderError"]
