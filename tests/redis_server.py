"""A real Redis for the farm tests, and real ``tween worker`` processes against it.

Uses the Redis on 127.0.0.1:6379 when it answers PING; otherwise starts a private
``redis-server`` on a free port (installing it with apt when missing, if root and apt exist).
Each test session gets its own key prefix (queues, unacked sets, results all live under it)
and deletes its keys afterwards; a server it did not start is never stopped.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import redis

REPO = Path(__file__).resolve().parents[1]


def _ping(url: str) -> bool:
    try:
        return bool(redis.Redis.from_url(url, socket_connect_timeout=1, socket_timeout=2).ping())
    except (redis.ConnectionError, redis.TimeoutError, OSError):
        return False


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _redis_server_binary() -> str:
    exe = shutil.which("redis-server")
    if exe:
        return exe
    if os.geteuid() == 0 and shutil.which("apt-get"):
        env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
        subprocess.run(
            ["apt-get", "install", "-y", "-q", "redis-server"], env=env, check=False, capture_output=True
        )
        exe = shutil.which("redis-server")
        if exe:
            return exe
    raise RuntimeError(
        "no Redis on 127.0.0.1:6379 and no redis-server to start (apt-get install redis-server)"
    )


@dataclass
class RedisServer:
    url: str
    prefix: str
    proc: subprocess.Popen | None = None  # set only when this session started the server

    @property
    def client(self) -> redis.Redis:
        return redis.Redis.from_url(self.url)

    def keys(self) -> list[bytes]:
        return list(self.client.scan_iter(match=f"{self.prefix}*", count=1000))

    def cleanup(self) -> None:
        """Deletes this session's keys; stops the server only if this session started it."""
        keys = self.keys()
        if keys:
            self.client.delete(*keys)
        if self.proc is not None:
            self.proc.terminate()
            self.proc.wait(timeout=10)


def start_redis() -> RedisServer:
    prefix = f"tween-test-{uuid.uuid4().hex[:10]}:"
    url = "redis://127.0.0.1:6379/0"
    if _ping(url):
        return RedisServer(url, prefix)
    port = _free_port()
    exe = _redis_server_binary()
    cmd = [exe, "--port", str(port), "--bind", "127.0.0.1", "--save", "", "--appendonly", "no"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    url = f"redis://127.0.0.1:{port}/0"
    for _ in range(100):
        if _ping(url):
            return RedisServer(url, prefix, proc)
        time.sleep(0.05)
    proc.kill()
    raise RuntimeError(f"redis-server on port {port} did not answer")


def farm_env(server: RedisServer, roots: list[str], **overrides) -> dict[str, str]:
    """Environment of a farm client or worker on ``server`` with test-sized takeover timings."""
    env = {
        "TWEEN_BROKER_URL": server.url,
        "TWEEN_RESULT_BACKEND": server.url,
        "TWEEN_KEY_PREFIX": server.prefix,
        "TWEEN_SHOT_ROOTS": os.pathsep.join(roots),
        "TWEEN_QUEUE": f"{server.prefix}fill",
        "TWEEN_FARM_CONFIG": os.devnull,
    }
    env.update({k: str(v) for k, v in overrides.items()})
    return env


@dataclass
class Worker:
    """A real ``tween worker`` subprocess in its own process group (so it can die as a host)."""

    proc: subprocess.Popen
    log: Path
    name: str

    @property
    def pgid(self) -> int:
        return self.proc.pid  # start_new_session: the main process leads its group

    def kill_host(self) -> None:
        """SIGKILL the main process and every pool child at once, like a host losing power."""
        os.killpg(self.pgid, signal.SIGKILL)
        self.proc.wait(timeout=10)

    def stop(self, deadline: float | None = None) -> None:
        """Warm shutdown (SIGTERM), killed if it has not ended by ``deadline`` (monotonic;
        15 s from now by default)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        self.wait_stopped(time.monotonic() + 15 if deadline is None else deadline)

    def wait_stopped(self, deadline: float) -> None:
        try:
            self.proc.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            os.killpg(self.pgid, signal.SIGKILL)
            self.proc.wait()

    def log_text(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""


@dataclass
class WorkerPool:
    env: dict
    log_dir: Path
    workers: list[Worker] = field(default_factory=list)

    def start(self, concurrency: int = 1, include: list[str] = (), **env) -> Worker:
        name = f"w{len(self.workers)}-{uuid.uuid4().hex[:6]}"
        log = self.log_dir / f"{name}.log"
        cmd = [sys.executable, "-m", "pipeline.cli", "worker", "-c", str(concurrency), "-n", f"{name}@%h"]
        cmd += ["--logfile", str(log), "-l", "info"]
        for mod in include:
            cmd += ["--include", mod]
        full_env = {**os.environ, **self.env, **{k: str(v) for k, v in env.items()}}
        full_env["PYTHONPATH"] = os.pathsep.join([str(REPO), full_env.get("PYTHONPATH", "")]).rstrip(
            os.pathsep
        )
        with open(log.with_suffix(".out"), "wb") as out:
            proc = subprocess.Popen(
                cmd, cwd=REPO, env=full_env, start_new_session=True, stdout=out, stderr=subprocess.STDOUT
            )
        w = Worker(proc, log, name)
        self.workers.append(w)
        return w

    def wait_ready(self, timeout: float = 60) -> None:
        t0 = time.monotonic()
        for w in self.workers:
            while " ready." not in w.log_text():
                if w.proc.poll() is not None:
                    raise RuntimeError(
                        f"worker {w.name} exited: {w.log.with_suffix('.out').read_text()[-2000:]}"
                    )
                if time.monotonic() - t0 > timeout:
                    raise TimeoutError(f"worker {w.name} not ready after {timeout} s")
                time.sleep(0.1)

    def stop_all(self) -> None:
        """Every worker told to stop at once, then waited for: each warm stop takes seconds."""
        for w in self.workers:
            if w.proc.poll() is None:
                w.proc.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + 15
        for w in self.workers:
            w.wait_stopped(deadline)


# --- shots -------------------------------------------------------------------------------


def example_shot() -> Path:
    """The example shot of examples/ (the one `make demo` fills); until one is committed, a
    short walk converted from the shared Bandai data with a key every 8 frames."""
    shots = sorted(
        p
        for p in (REPO / "examples").glob("*.usd*")
        if p.is_file() and ".tween." not in p.name and ".review." not in p.name
    )
    if shots:
        return shots[0]
    from pipeline.data.split import shared_data_dir
    from pipeline.motion.bvh import read_bvh
    from pipeline.usd.convert import write_shot

    out = REPO / ".cache" / "tests" / "farm" / "walk_example.usda"
    if not out.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
        clip = shared_data_dir() / "bandai_namco" / "dataset-2" / "dataset-2_walk_active_002.bvh.gz"
        write_shot(read_bvh(clip).slice(0, 61), out, keys_every=8)
    return out


def copy_shot(src: Path, dst_dir: Path, name: str) -> Path:
    """Copies a shot (and any files beside it that it references) as ``name`` in ``dst_dir``."""
    dst_dir.mkdir(parents=True, exist_ok=True)
    dst = dst_dir / f"{name}{src.suffix}"
    shutil.copyfile(src, dst)
    return dst


def layer_samples(path: str | Path) -> dict:
    """Every time-sampled attribute of a layer: {attribute path: [(time, numpy value)]}."""
    import numpy as np
    from pxr import Sdf

    layer = Sdf.Layer.OpenAsAnonymous(str(path))
    out = {}

    def visit(p):
        spec = layer.GetObjectAtPath(p)
        if isinstance(spec, Sdf.AttributeSpec) and layer.ListTimeSamplesForPath(p):
            out[str(p)] = [
                (t, np.asarray(layer.QueryTimeSample(p, t), dtype=np.float64))
                for t in layer.ListTimeSamplesForPath(p)
            ]

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return out


def assert_same_samples(a: dict, b: dict, atol: float = 1e-5) -> None:
    import numpy as np

    assert a, "layer has no animation samples"
    assert sorted(a) == sorted(b)
    for k in a:
        ta, tb = [t for t, _ in a[k]], [t for t, _ in b[k]]
        assert ta == tb, k
        for (_, va), (_, vb) in zip(a[k], b[k], strict=True):
            np.testing.assert_allclose(va, vb, atol=atol, err_msg=k)


def leftovers(folder: Path) -> list[str]:
    """Temp files and work folders a job must not leave behind."""
    bad = []
    for p in folder.rglob("*"):
        n = p.name
        if n.startswith(".tmp") or n.endswith((".tmp", ".partial")) or n == ".tween-work" or ".tmp-" in n:
            bad.append(str(p))
    return bad


def configure_app(app, settings) -> None:
    """Points this test process's Celery ``app`` at ``settings`` (workers.app.configure), and
    drops what it cached under earlier settings: its result backend and its connection and
    producer pools (each test module's farm has its own Redis key prefix)."""
    from kombu import pools

    from workers.app import configure

    configure(app, settings)
    app._backend_cache = None
    app._local.__dict__.pop("backend", None)
    app._pool = None
    amqp = app.__dict__.get("amqp")
    if amqp is not None:
        amqp._producer_pool = None
    pools.reset()
