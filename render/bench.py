"""Speed of a review turntable: ``python -m render.bench``;
``--png`` adds the numbered frames, ``--side-by-side`` the blocking panel, ``--fixed`` the
original (not following) camera.

Converts a real 300-frame Bandai clip (10 s at 30 fps) with ``pipeline.usd.convert``, fills it
with the interpolation model (keys every 10 frames), then renders the review at 960x540 with
4x MSAA into an H.264 MP4 plus a contact sheet in this one process, and prints the timings.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path

from pipeline.arguments import Parser
from pipeline.data.split import shared_data_dir
from pipeline.fill.api import FillOptions, fill_shot
from render.gl import renderer_name
from render.review import render_review

CLIP = "bandai_namco/dataset-1/dataset-1_dance-short_normal_001.bvh.gz"


def bench(
    frames: int = 300,
    size=(960, 540),
    write_frames: bool = False,
    side_by_side: bool = False,
    framing: str = "follow",
) -> dict:
    from pipeline.motion.bvh import read_bvh
    from pipeline.usd.convert import write_shot

    with tempfile.TemporaryDirectory(prefix="tween-bench-render-") as work:
        motion = read_bvh(shared_data_dir() / CLIP).slice(0, frames)
        shot = write_shot(motion, Path(work) / "bench.usda", keys_every=10)
        review = fill_shot(shot, FillOptions(model="interp", out_dir=work))["review"]
        renderer_name()  # the EGL context is made once per process (a worker keeps it): not timed
        t0 = time.perf_counter()
        out = render_review(review, str(Path(work) / "out"), size=size, write_frames=write_frames,
                            side_by_side=side_by_side, framing=framing)  # fmt: skip
        wall = time.perf_counter() - t0
        mp4_kb = os.path.getsize(out["mp4"]) // 1024
    return {
        "frames": len(out["frame_numbers"]),
        "size": f"{size[0]}x{size[1]}",
        "msaa": 4,
        "png_frames": write_frames,
        "side_by_side": side_by_side,
        "framing": framing,
        "wall_s": round(wall, 2),
        "frames_per_s": round(len(out["frame_numbers"]) / wall, 1),
        "mp4_kb": mp4_kb,
        "renderer": renderer_name(),
        "LP_NUM_THREADS": os.environ.get("LP_NUM_THREADS"),
        "cpus": os.cpu_count(),
        "load_avg_1m": round(os.getloadavg()[0], 2),
    }


def main(argv: list[str] | None = None) -> int:
    ap = Parser(prog="python -m render.bench", description=__doc__.splitlines()[0])
    ap.add_argument("--png", action="store_true", help="also write the numbered frames")
    ap.add_argument("--side-by-side", action="store_true", help="with the blocking panel")
    ap.add_argument("--fixed", action="store_true", help="the original camera, not following")
    a = ap.parse_args(argv)
    res = bench(write_frames=a.png, side_by_side=a.side_by_side, framing="fixed" if a.fixed else "follow")
    print(json.dumps(res))
    return 0


if __name__ == "__main__":
    from pipeline.command import run_main
    from pipeline.data.cache_paths import cache_root

    run_main(main, log_dir=cache_root() / "logs")  # a bug's traceback goes there, as tween's
