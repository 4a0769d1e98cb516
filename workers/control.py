"""A fill job's control records: its cancel record and the heartbeats of its running stages.

Both live in the result backend beside the job record (``workers/jobs.py``), so they work on
every farm (Redis, RabbitMQ + a database backend, the embedded SQLite farm), survive worker
restarts, and need no broadcast:

* ``<job>.cancel``: written by ``tween cancel`` or an interrupted ``tween fill``. Every stage
  reads it when it starts (a cancelled job's stage undoes the job and exits at once, whichever
  worker gets it, started before or after the cancel) and at each heartbeat while it runs (it
  is then interrupted where it is, cleans up, and fails with "cancelled").
* ``<stage task id>.beat``: written every ``heartbeat_interval`` seconds by the stage that
  runs (worker, pid, host, start, last beat). On Redis each beat also renews the stage's
  message lease (its score in the broker's ``unacked_index``), so a stage may run longer than
  ``visibility_timeout`` and a dead worker's stage is still requeued ``visibility_timeout``
  after its last heartbeat. A stage that starts where an earlier run left a beat that never
  ended was requeued: the new beat says when, and from which worker.
"""

from __future__ import annotations

import getpass
import json
import os
import signal
import socket
import sys
import threading
import time
from contextlib import contextmanager

CANCEL_STATE = "CANCELLED"
BEAT_STATE = "HEARTBEAT"
#: Signal the watcher sends to its own pool process to interrupt a cancelled stage.
CANCEL_SIGNAL = signal.SIGUSR2


class JobCancelled(BaseException):
    """Raised in a running stage whose job was cancelled. A BaseException, like
    KeyboardInterrupt, so that no ``except Exception`` on the way swallows it."""


def cancel_id(job_id: str) -> str:
    return f"{job_id}.cancel"


def beat_id(task_id: str) -> str:
    return f"{task_id}.beat"


def _backend(app):
    return app.backend


def record(meta: dict, state: str) -> dict | None:
    """The record in a result-backend entry ``meta`` stored under ``state``, or None."""
    if meta.get("status") == state and isinstance(meta.get("result"), dict):
        return meta["result"]
    return None


def cancel_record(app, job_id: str) -> dict | None:
    """The job's cancel record ({"time", "by"}), or None."""
    return record(_backend(app).get_task_meta(cancel_id(job_id)), CANCEL_STATE)


def request_cancel(app, job_id: str, why: str = "") -> dict:
    """Writes the job's cancel record (kept if there is one already); returns it."""
    old = cancel_record(app, job_id)
    if old:
        return old
    rec = {"time": time.time(), "by": f"{getpass.getuser()}@{socket.gethostname()}", "why": why}
    _backend(app).store_result(cancel_id(job_id), rec, CANCEL_STATE)
    return rec


def read_beat(app, task_id: str) -> dict | None:
    return record(_backend(app).get_task_meta(beat_id(task_id)), BEAT_STATE)


def dead_after(settings, beat: dict | None = None) -> float:
    """Seconds without a heartbeat after which a running stage's worker counts as dead: three
    of the beat's own interval (its worker's setting, which the beat records: a client with a
    shorter one called a healthy worker lost), or of ``settings``' for a beat without it."""
    interval = (beat or {}).get("interval")
    if not isinstance(interval, (int, float)) or isinstance(interval, bool) or not interval > 0:
        interval = settings.heartbeat_interval
    return max(3.0 * float(interval), 3.0)


# --- in the pool process: the watch over a running stage --------------------------------

_ARMED = threading.Event()


def _on_cancel_signal(signum, frame):
    if _ARMED.is_set():
        _ARMED.clear()
        raise JobCancelled()


def install_signal() -> None:
    """The cancel signal's handler, in the pool process's main thread. Installed when a stage
    starts, not at fork: billiard resets the pool process's signals after its initializer."""
    if signal.getsignal(CANCEL_SIGNAL) is not _on_cancel_signal:
        signal.signal(CANCEL_SIGNAL, _on_cancel_signal)


class _RedisLease:
    """Renews the running stage's message in the Redis broker's ``unacked_index`` (the
    delivery time kombu restores it by), found by its task id in the ``unacked`` hash."""

    def __init__(self, app, task_id: str):
        self.app, self.task_id, self.tag = app, task_id, None
        self.conn = app.connection_for_write()
        self.channel = self.conn.default_channel

    def _find(self):
        ch = self.channel
        prefix = getattr(ch, "global_keyprefix", "") or ""
        client = ch.client
        for tag, raw in client.hscan_iter(prefix + ch.unacked_key):
            try:
                msg = json.loads(raw)[0]
            except (ValueError, TypeError, IndexError):
                continue
            if (msg.get("headers") or {}).get("id") == self.task_id:
                return tag
        return None

    def renew(self) -> None:
        if self.tag is None:
            self.tag = self._find()
            if self.tag is None:
                return
        # XX: only a message still held; one that was acked or restored is left alone.
        self.channel.client.zadd(self.channel.unacked_index_key, {self.tag: time.time()}, xx=True)

    def close(self) -> None:
        try:
            self.conn.release()
        except Exception:
            pass


class StageWatch:
    """Heartbeats, lease renewal and the cancel check of one running stage (a thread)."""

    def __init__(self, app, job_id: str, task_id: str, stage: str, worker: str = ""):
        self.app, self.job_id, self.task_id, self.stage = app, job_id, task_id, stage
        self.settings = app.conf.tween
        self.worker = worker or f"pid {os.getpid()}"
        self.started = time.time()
        self.previous = None  # the beat an earlier run of this stage left, never ended
        self.requeued: list = []
        self.cancelled = None
        self._stop = threading.Event()
        self._thread = None
        self._lease = None

    def beat(self, ended: bool = False) -> None:
        rec = {
            "job": self.job_id,
            "task": self.task_id,
            "stage": self.stage,
            "worker": self.worker,
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "started": self.started,
            "time": time.time(),
            "ended": ended,
            "requeued": self.requeued,
            "interval": self.settings.heartbeat_interval,  # how soon the next one comes
        }
        _backend(self.app).store_result(beat_id(self.task_id), rec, BEAT_STATE)

    def start(self) -> StageWatch:
        install_signal()
        prev = read_beat(self.app, self.task_id)
        if prev and not prev.get("ended"):
            # An earlier run of this stage never ended: its worker died and the broker
            # requeued the stage (or this is the same message delivered again).
            self.previous = prev
            self.requeued = list(prev.get("requeued") or []) + [
                {
                    "at": self.started,
                    "from": prev.get("worker"),
                    "host": prev.get("host"),
                    "pid": prev.get("pid"),
                    "last_beat": prev.get("time"),
                }  # fmt: skip
            ]
        elif prev:
            self.requeued = list(prev.get("requeued") or [])
        self.beat()
        if self.settings.is_redis:
            try:
                self._lease = _RedisLease(self.app, self.task_id)
            except Exception as e:  # the stage still runs; it is only requeued sooner
                print(f"tween worker: no lease renewal for {self.task_id}: {e}", file=sys.stderr)
        _ARMED.set()
        self._thread = threading.Thread(target=self._run, name="tween-stage-watch", daemon=True)
        self._thread.start()
        return self

    def _tick(self) -> None:
        self.beat()
        if self._lease is not None:
            self._lease.renew()
        if self.cancelled is None:
            rec = cancel_record(self.app, self.job_id)
            if rec:
                self.cancelled = rec
                if _ARMED.is_set():
                    os.kill(os.getpid(), CANCEL_SIGNAL)

    def _run(self) -> None:
        interval = float(self.settings.heartbeat_interval)
        while not self._stop.wait(interval):
            try:
                self._tick()
            except Exception as e:  # a backend hiccup: the next beat tries again
                print(f"tween worker: heartbeat of {self.task_id}: {e}", file=sys.stderr)

    def stop(self) -> None:
        _ARMED.clear()
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
        if self._lease is not None:
            self._lease.close()
        try:
            self.beat(ended=True)
        except Exception:
            pass


@contextmanager
def watch(app, job_id: str, task_id: str, stage: str, worker: str = ""):
    """Runs a stage under a :class:`StageWatch`. Raises :class:`JobCancelled` at once when
    the job is cancelled already, inside the body when it is cancelled while it runs, and
    after the body when the cancel came in the last moments (the stage's output must then be
    undone too)."""
    if cancel_record(app, job_id):
        raise JobCancelled()
    w = StageWatch(app, job_id, task_id, stage, worker)
    try:
        w.start()
        yield w
    finally:
        w.stop()
    if w.cancelled or cancel_record(app, job_id):
        raise JobCancelled()
