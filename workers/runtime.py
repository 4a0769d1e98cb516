"""Per-worker-process state: thread budgets, and the in-betweener loaded once after fork."""

from __future__ import annotations

import ctypes
import json
import os
import signal
import sys
import threading
import time

from pipeline.fill import api as fill

#: Set by the embedded launcher in its worker's environment: the pid of the `tween fill`
#: client. A worker with it dies with that client (the embedded farm is the client's own).
PARENT_ENV = "TWEEN_EMBEDDED_PARENT"
PR_SET_PDEATHSIG = 1


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
        "TWEEN_ORT_THREADS": n,  # intra-op threads of the ORT sessions (pipeline.infer.generator_onnx)
    }


def get_inbetweener(name: str = "default"):
    """The process's in-betweener for ``name``, loaded on first use and kept (pipeline.fill caches it)."""

    return fill._model(name)


def init_process() -> None:
    """Runs in each pool child after fork: loads the default model once, and keeps it."""
    try:
        get_inbetweener(os.environ.get("TWEEN_WORKER_MODEL", "default"))
    except Exception as e:  # a missing model must not kill the pool; the task reports it
        print(f"tween worker: model not preloaded: {e}", file=sys.stderr)


def small_json(value) -> dict | list | str | int | float | bool | None:
    """``value`` reduced to JSON types (paths and numbers); anything else becomes its str()."""
    return json.loads(json.dumps(value, default=str))


def set_pdeathsig(sig: int = signal.SIGKILL) -> bool:
    """Linux: ``sig`` is sent to this process when its parent (thread) exits. False elsewhere."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def die_with(parent: int, sig: int = signal.SIGKILL) -> None:
    """This process dies when ``parent`` does: PR_SET_PDEATHSIG where there is one; exits at
    once when ``parent`` is gone already (it died before the death signal was set)."""
    set_pdeathsig(sig)
    if os.getppid() != parent:
        os._exit(1)


def _kill_group() -> None:
    try:
        os.killpg(os.getpgrp(), signal.SIGKILL)
    finally:
        os._exit(1)


def watch_parent(parent: int, interval: float = 0.25) -> threading.Thread:
    """Portable fallback of :func:`die_with` for a whole worker: a daemon thread that kills
    this process group (the worker and its pool) as soon as this process's parent is no longer
    ``parent`` (it died, and this process was re-parented)."""

    def run():
        while True:
            if os.getppid() != parent:
                _kill_group()
            time.sleep(interval)

    t = threading.Thread(target=run, name="tween-parent-watch", daemon=True)
    t.start()
    return t
