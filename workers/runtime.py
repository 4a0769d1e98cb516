"""Per-worker-process state: thread budgets, and the in-betweener loaded once after fork."""

from __future__ import annotations

import json
import os


def thread_budget(concurrency: int, cpus: int | None = None) -> int:
    """Threads per pool process so that ORT, torch and llvmpipe do not oversubscribe the cores."""
    cpus = cpus or os.cpu_count() or 1
    return max(1, cpus // max(1, concurrency))


def thread_env(concurrency: int) -> dict[str, str]:
    """Environment for a worker with ``concurrency`` pool processes (set before ORT/GL load)."""
    n = str(thread_budget(concurrency))
    return {
        "OMP_NUM_THREADS": n,
        "MKL_NUM_THREADS": n,
        "OPENBLAS_NUM_THREADS": n,
        "LP_NUM_THREADS": n,  # Mesa llvmpipe render threads
        "TWEEN_ORT_THREADS": n,  # intra-op threads of the ORT sessions (pipeline.infer.model)
    }


def get_inbetweener(name: str = "default"):
    """The process's in-betweener for ``name``, loaded on first use and kept (pipeline.fill caches it)."""
    from pipeline import fill

    return fill._model(name)


def init_process() -> None:
    """Runs in each pool child after fork: loads the default model once, and keeps it."""
    try:
        get_inbetweener(os.environ.get("TWEEN_WORKER_MODEL", "default"))
    except Exception as e:  # a missing model must not kill the pool; the task reports it
        import sys

        print(f"tween worker: model not preloaded: {e}", file=sys.stderr)


def small_json(value) -> dict | list | str | int | float | bool | None:
    """``value`` reduced to JSON types (paths and numbers); anything else becomes its str()."""
    return json.loads(json.dumps(value, default=str))
