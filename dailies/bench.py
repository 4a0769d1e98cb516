"""Speed of the dailies page: ``python -m dailies.bench [--shots 50] [--viewers 20] [--seconds 10]``.

Fills a real Bandai clip with two takes and renders them as the farm does, copies that shot
``--shots`` times under one root, serves it with ``tween dailies`` on loopback, then measures:
the shot list's load time (cold, then warm), one shot page's, ``--viewers`` concurrent viewers
each scrubbing (range requests at random offsets of every take's MP4, as seeking does) for
``--seconds``, and, where ``/usr/bin/chromium`` and Playwright are present, how long a take
takes to start playing in a real browser. Bounded: it stops after ``--seconds``.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

from pipeline.data.split import shared_data_dir

CLIP = "bandai_namco/dataset-2/dataset-2_walk_active_002.bvh.gz"
TOKEN = "bench" * 8
CHROMIUM = "/usr/bin/chromium"


def make_shots(root: Path, count: int, frames: int = 90, size=(480, 270)) -> str:
    """``count`` copies of one filled, rendered shot (``seqNNN/sh010``); returns one's key."""
    from pipeline.fill.api import FillOptions, fill_shot
    from pipeline.motion.bvh import read_bvh
    from pipeline.usd.convert import write_shot
    from render.review import render_review

    first = root / "seq000"
    first.mkdir(parents=True)
    shot = write_shot(
        read_bvh(shared_data_dir() / CLIP).slice(0, frames), first / "sh010.usda", keys_every=10
    )
    r = fill_shot(str(shot), FillOptions(model="interp", takes=2))
    for t in (0, 1):
        render_review(r["review"], str(first / "review"), take=t, size=size, write_frames=False)
    for i in range(1, count):
        shutil.copytree(first, root / f"seq{i:03d}")
    return "0/seq000/sh010"


def _get(url: str, headers: dict | None = None) -> tuple[int, bytes, float]:
    req = urllib.request.Request(url, headers={"Authorization": f"Bearer {TOKEN}", **(headers or {})})
    t0 = time.perf_counter()
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            return r.status, r.read(), time.perf_counter() - t0
    except urllib.error.HTTPError as e:
        return e.code, b"", time.perf_counter() - t0


def _ms(xs: list[float]) -> dict:
    xs = sorted(xs)
    return {"median_ms": round(1000 * statistics.median(xs), 1),
            "p95_ms": round(1000 * xs[min(len(xs) - 1, int(0.95 * len(xs)))], 1), "n": len(xs)}  # fmt: skip


def viewers(base: str, key: str, mp4s: list[tuple[str, int]], n: int, seconds: float) -> dict:
    """``n`` threads, each loading the page, then seeking at random in every take's MP4."""
    lat, errors, lock = [], [], threading.Lock()
    stop = time.monotonic() + seconds

    def viewer(seed: int) -> None:
        rng = random.Random(seed)
        status, _, dt = _get(f"{base}/shot/{key}")
        local, errs = [dt], [] if status == 200 else [f"page {status}"]
        while time.monotonic() < stop:
            for url, size in mp4s:
                a = rng.randrange(0, max(1, size - 65536))
                status, body, dt = _get(base + url, {"Range": f"bytes={a}-{a + 65535}"})
                local.append(dt)
                if status != 206 or len(body) != min(65536, size - a):
                    errs.append(f"{url} {status} {len(body)}")
        with lock:
            lat.extend(local)
            errors.extend(errs)

    threads = [threading.Thread(target=viewer, args=(i,)) for i in range(n)]
    t0 = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    wall = time.perf_counter() - t0
    return {"viewers": n, "seconds": round(wall, 1), "requests": len(lat), "errors": len(errors),
            "first_errors": errors[:5], "requests_per_s": round(len(lat) / wall, 1), **_ms(lat)}  # fmt: skip


def playing(url: str, base: str, key: str) -> dict | None:
    """Milliseconds from opening the shot page to every take playing, in chromium."""
    if not os.path.exists(CHROMIUM):
        return None
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        return None
    out = []
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM)
        page = browser.new_page()
        page.goto(url)
        for _ in range(5):
            t0 = time.perf_counter()
            page.goto(f"{base}/shot/{key}")
            page.click("#play")
            page.wait_for_function(
                "Array.from(document.querySelectorAll('video[data-take]')).every(v => !v.paused && v.currentTime > 0)"
            )
            out.append(time.perf_counter() - t0)
        browser.close()
    return _ms(out)


def run(shots: int, n_viewers: int, seconds: float) -> dict:
    with tempfile.TemporaryDirectory(prefix="tween-bench-dailies-") as work:
        root = Path(work)
        t0 = time.perf_counter()
        key = make_shots(root, shots)
        made = time.perf_counter() - t0
        server = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "dailies", str(root), "--port", "0",
                                   "--token", TOKEN], stdout=subprocess.PIPE, text=True)  # fmt: skip
        try:
            url = server.stdout.readline().strip()
            base = url.split("/?token=")[0]
            for _ in range(200):  # until uvicorn answers (a static file: no layer read yet)
                try:
                    _get(base + "/static/dailies.css")
                    break
                except urllib.error.URLError:
                    time.sleep(0.05)
            # The first listing right after start: the server reads every layer's metadata
            # at start-up (then the cache), so this is as cold as a supervisor can catch it.
            status, body, cold = _get(base + "/")
            assert status == 200 and body.count(b'href="/shot/') == shots, "the list does not show every shot"
            warm = [_get(base + "/")[2] for _ in range(20)]
            page = [_get(f"{base}/shot/{key}")[2] for _ in range(20)]
            detail = json.loads(_get(f"{base}/api/shots/{key}")[1])
            mp4s = [(t["mp4_url"], Path(t["mp4"]).stat().st_size) for t in detail["takes"]]
            load = viewers(base, key, mp4s, n_viewers, seconds)
            play = playing(url, base, key)
        finally:
            server.send_signal(signal.SIGINT)
            server.wait(30)
    return {"shots": shots, "setup_s": round(made, 1), "cpus": os.cpu_count(),
            "list_cold_ms": round(1000 * cold, 1), "list_warm": _ms(warm), "shot_page": _ms(page),
            "scrubbing": load, "start_playing": play}  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m dailies.bench", description=__doc__.split("\n")[0])
    ap.add_argument("--shots", type=int, default=50)
    ap.add_argument("--viewers", type=int, default=20)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--out", type=Path, default=Path("bench_results") / "dailies.json")
    a = ap.parse_args(argv)
    res = run(a.shots, a.viewers, a.seconds)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=1) + "\n")
    print(json.dumps(res, indent=1))
    print(f"written: {a.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
