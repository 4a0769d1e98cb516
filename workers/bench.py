"""``tween bench-farm``: shots per minute with N workers, and the Celery path's overhead.

Runs against the configured broker (TWEEN_BROKER_URL) with a private key prefix and queue,
starts ``tween worker -c 1`` processes itself (startup is not timed), and compares with
``pipeline.fill.fill_shot`` called directly in this process on the same shots.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

from pipeline.bench.outputs import check_out_file
from pipeline.errors import TweenError
from pipeline.fill.api import FillOptions, fill_shot, validate_shot
from workers import jobs
from workers.settings import cache_dir, load_settings


def _start_workers(n: int, env: dict, log_dir: Path, tag: str) -> list[subprocess.Popen]:
    procs = []
    for i in range(n):
        log = log_dir / f"worker{i}.log"
        cmd = [sys.executable, "-m", "pipeline.cli", "worker", "-c", "1", "-n", f"{tag}{i}@%h"]
        cmd += ["--logfile", str(log), "-l", "warning"]
        procs.append(
            subprocess.Popen(
                cmd, env=env, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
            )
        )
    return procs


def _stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    for p in procs:
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()


def _wait_ready(app, n: int, tag: str, timeout: float = 120) -> None:
    t0 = time.monotonic()
    # Other farms may share the broker: count only this run's workers.
    while sum(next(iter(r)).startswith(tag) for r in app.control.ping(timeout=1.0) or []) < n:
        if time.monotonic() - t0 > timeout:
            raise TweenError(f"bench-farm: {n} workers not ready after {timeout} s")


#: The repository's example shots (beside this package, wherever the command runs from).
EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
SHOT_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")


def _default_shot() -> Path:
    """The first example shot (not a fill or review layer)."""
    shots = sorted(p for p in EXAMPLES.glob("*.usd*") if ".tween." not in p.name and ".review." not in p.name)
    if not shots:
        raise TweenError(f"bench-farm: no example shot in {EXAMPLES} (pass --shot)")
    return shots[0]


def _check_shot(shot: Path) -> None:
    """Refuses a ``--shot`` that is no USD shot file, naming the user's file (not its copies)."""
    if not shot.is_file():
        what = "a folder" if shot.is_dir() else "no such file"
        raise TweenError(f"--shot {shot}: {what}; give a USD shot ({', '.join(SHOT_SUFFIXES)})")
    if shot.suffix.lower() not in SHOT_SUFFIXES:
        raise TweenError(f"--shot {shot}: not a USD shot ({', '.join(SHOT_SUFFIXES)})")


def _validate_shot(shot: Path, work: Path) -> None:
    """The fill's own checks of the user's shot (ShotError naming it), before it is copied."""
    validate_shot(str(shot), FillOptions(out_dir=str(work / "direct")))


def _direct_s_per_shot(copies: list[Path], work: Path) -> float:
    """Seconds per shot of ``fill_shot`` in this process, on the copies (after one warm-up fill)."""
    fill_shot(str(copies[0]), FillOptions(out_dir=str(work / "warm")))
    t0 = time.perf_counter()
    for c in copies:
        fill_shot(str(c), FillOptions(out_dir=str(work / "direct")))
    return (time.perf_counter() - t0) / len(copies)


def _farm_row(app, n: int, env: dict, work: Path, copies: list[Path]) -> dict:
    """The copies filled by ``n`` fresh workers (their start-up not timed): the table's row."""
    tag = f"bench-{work.name}-{n}w"
    procs = _start_workers(n, env, work, tag)
    try:
        _wait_ready(app, n, tag)
        opts = jobs.make_opts(out_dir=str(work / f"farm{n}"))
        t0 = time.perf_counter()
        states = jobs.wait(jobs.submit([str(c) for c in copies], opts), progress=False)
        wall = time.perf_counter() - t0
    finally:
        _stop(procs)
    failed = [s.error for s in states if s.state != "SUCCESS"]
    if failed:
        raise TweenError(f"bench-farm: {len(failed)} shots failed: {failed[0]}")
    return {"workers": n, "wall_s": round(wall, 2), "shots_per_min": round(60 * len(copies) / wall, 1)}


def _markdown(res: dict, overhead: float | None, broker_url: str) -> str:
    n_shots, rows = res["shots"], res["farm"]
    lines = [
        f"bench-farm: {n_shots} copies of {res['shot']}, {os.cpu_count()} CPUs, broker {broker_url.split('@')[-1]}",
        "",
        "| path | shots/min | s/shot |",
        "|---|---|---|",
        f"| direct fill_shot, 1 process | {res['direct_shots_per_min']} | {res['direct_s_per_shot']} |",
    ]
    lines += [
        f"| Celery, {r['workers']} worker(s) -c 1 | {r['shots_per_min']} | {r['wall_s'] / n_shots:.3f} |"
        for r in rows
    ]
    if overhead is not None:
        lines += [
            "",
            f"Celery overhead: {overhead:.3f} s per shot = {res['overhead_pct_of_10s_shot']} % of a 10 s shot.",
        ]
    return "\n".join(lines)


def run_bench_farm(n_shots: int, worker_counts: list[int], shot: Path | None, out: Path) -> dict:
    from workers.app import SETTINGS_ERROR, app, check_farm, configure

    check_out_file(out)  # before the farm runs, not after
    shot = _default_shot() if shot is None else shot
    _check_shot(shot)
    base = app.conf.tween
    if SETTINGS_ERROR is not None:  # the broker setting may be the one that is wrong
        raise SETTINGS_ERROR
    if base.embedded:
        raise TweenError("bench-farm needs a broker: set TWEEN_BROKER_URL (e.g. redis://127.0.0.1:6379/0)")
    check_farm(app)  # an unreachable broker or backend: one line, before any fill runs
    work = cache_dir() / "bench-farm" / uuid.uuid4().hex[:8]
    _validate_shot(shot, work)
    prefix = f"tween-bench-{work.name}:"
    env = dict(os.environ, TWEEN_KEY_PREFIX=prefix, TWEEN_QUEUE=f"{prefix}fill", TWEEN_SHOT_ROOTS=str(work))
    configure(app, load_settings(env))

    try:
        src = work / "src"
        src.mkdir(parents=True)
        copies = [src / f"sh{i:03d}{shot.suffix}" for i in range(n_shots)]
        for c in copies:
            shutil.copyfile(shot, c)
        direct = _direct_s_per_shot(copies, work)
        rows = [_farm_row(app, n, env, work, copies) for n in worker_counts]
        one = next((r for r in rows if r["workers"] == 1), None)
        overhead = (one["wall_s"] / n_shots - direct) if one else None
        res = {
            "shot": str(shot),
            "shots": n_shots,
            "cpus": os.cpu_count(),
            "direct_s_per_shot": round(direct, 3),
            "direct_shots_per_min": round(60 / direct, 1),
            "farm": rows,
            "celery_overhead_s_per_shot": None if overhead is None else round(overhead, 3),
            "overhead_pct_of_10s_shot": None if overhead is None else round(100 * overhead / 10, 2),
        }
    finally:
        configure(app, base)
        _cleanup_keys(base, prefix)
        shutil.rmtree(work, ignore_errors=True)
    res["markdown"] = _markdown(res, overhead, base.broker_url)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=1))
    return res


def _cleanup_keys(s, prefix: str) -> None:
    if not s.is_redis:
        return
    import redis

    r = redis.Redis.from_url(s.broker_url)
    keys = list(r.scan_iter(match=f"{prefix}*", count=1000))
    if keys:
        r.delete(*keys)
