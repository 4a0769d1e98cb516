"""The farm with RabbitMQ as the broker (Redis as the result store): one real fill end to end.

These machines start RabbitMQ on 127.0.0.1:5672; if it is down the test starts it the way
the machine does (``rabbitmq-server -detached``) and fails if it still does not answer.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
import uuid

from redis_server import REPO, WorkerPool, copy_shot, example_shot, farm_env, layer_samples, start_redis

AMQP = ("127.0.0.1", 5672)


def _amqp_up() -> bool:
    try:
        socket.create_connection(AMQP, timeout=1).close()
        return True
    except OSError:
        return False


def _ensure_rabbitmq(timeout: float = 60) -> None:
    if _amqp_up():
        return
    if shutil.which("rabbitmq-server"):
        subprocess.run(["rabbitmq-server", "-detached"], capture_output=True, timeout=30)
    t0 = time.monotonic()
    while not _amqp_up():
        assert time.monotonic() - t0 < timeout, "RabbitMQ does not answer on 127.0.0.1:5672"
        time.sleep(1)


def _delete_queue(name: str) -> None:
    from kombu import Connection

    with Connection("amqp://guest:guest@127.0.0.1:5672//") as conn:
        ch = conn.channel()
        try:
            ch.queue_delete(name)
        except Exception:  # already gone
            pass


def test_fill_through_rabbitmq(tmp_path):
    _ensure_rabbitmq()
    server = start_redis()
    queue = f"tween-test-{uuid.uuid4().hex[:8]}"
    shot = copy_shot(example_shot(), tmp_path / "shots", "rmq")
    env = farm_env(server, [str(tmp_path / "shots")])
    env.update(TWEEN_BROKER_URL="amqp://guest:guest@127.0.0.1:5672//", TWEEN_QUEUE=queue)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), str(REPO / "tests")])
    pool = WorkerPool(env, tmp_path)
    try:
        pool.start(concurrency=1)
        pool.wait_ready()
        cmd = [sys.executable, "-m", "pipeline.cli", "fill", str(shot), "--no-progress"]
        res = subprocess.run(
            cmd, cwd=REPO, env={**os.environ, **env}, capture_output=True, text=True, timeout=120
        )
        assert res.returncode == 0, res.stderr[-2000:]
        layer = res.stdout.split("layer ", 1)[1].split(",")[0].strip()
        samples = layer_samples(layer)
        assert samples and all(len(v) > 90 for v in samples.values())  # every frame 1001-1097
        assert "tween.fill_take" in pool.workers[0].log_text()
    finally:
        pool.stop_all()
        _delete_queue(queue)
        server.cleanup()
