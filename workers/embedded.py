"""The embedded default: a private worker process on the server-less SQLite broker.

With no broker configured, ``tween fill`` starts ``tween worker`` itself on a private queue
of the SQLite broker under the cache folder, submits through Celery as on a farm, waits, and
stops the worker. The worker's shot roots are the folders of the shots on the command line.
"""

from __future__ import annotations

import functools
import json
import os
import signal
import subprocess
import sys
import time
import uuid

from pipeline.errors import TweenError
from workers import runtime
from workers.errors import STORE_FULL_EXIT, StoreFullError, store_full
from workers.settings import EMBEDDED_QUEUE_PREFIX, cache_dir

#: How long the embedded worker is given to stop warm (it stops its pool) before it is killed.
WARM_STOP_S = 20.0


class WorkerDied(TweenError):
    """The embedded worker exited while its jobs ran."""


class WorkerStoreFull(WorkerDied):
    """The embedded worker ended because its broker or result store cannot grow."""


class EmbeddedWorker:
    """Context manager: a ``tween worker`` subprocess (own session) on a private queue."""

    def __init__(
        self, roots: list[str], concurrency: int = 2, extra_args: list[str] | None = None, hurry=None
    ):
        self.queue = f"{EMBEDDED_QUEUE_PREFIX}{uuid.uuid4().hex[:12]}"
        self.roots = sorted({os.path.realpath(r) for r in roots})
        self.concurrency = concurrency
        self.extra_args = list(extra_args or [])
        self.folder = cache_dir() / "farm"  # its broker and result store, and its log
        self.log = self.folder / "logs" / f"{self.queue}.log"
        self.proc: subprocess.Popen | None = None
        # Set once every job it was given has ended (reported, or cancelled and stopped): it is
        # idle and is killed, not stopped warm, which took 4-6 s of Celery's pool and thread
        # joins after the fill's results were out, and its messages are gone with its queue.
        self.cold = False
        # Polled while it stops: true once its client was told to stop (SIGINT, SIGTERM), which
        # then ends the worker at once rather than wait for its warm shutdown (seconds).
        self.hurry = hurry or (lambda: False)

    def __enter__(self) -> EmbeddedWorker:
        self.log.parent.mkdir(parents=True, exist_ok=True)
        env = dict(os.environ, TWEEN_SHOT_ROOTS=json.dumps(list(self.roots)))  # a root may hold ":"
        # The worker dies with this client, even on SIGKILL: PR_SET_PDEATHSIG on Linux (set in
        # the child before exec; its pool children set theirs), and a watchdog thread in the
        # worker that kills its process group once this pid is no longer its parent.
        env[runtime.PARENT_ENV] = str(os.getpid())
        env.pop("TWEEN_BROKER_URL", None)
        cmd = [
            sys.executable,
            "-m",
            "pipeline.cli",
            "worker",
            "--queue",
            self.queue,
            "-c",
            str(self.concurrency),
        ]
        cmd += ["--hostname", f"{self.queue}@%h", "--logfile", str(self.log), *self.extra_args]
        # Own session: the whole worker (main process and pool children) stops as one group.
        # Its output goes to the log: stdout of `tween fill` carries only results.
        try:
            with open(self.log, "ab") as logf:
                self.proc = subprocess.Popen(
                    cmd,
                    env=env,
                    start_new_session=True,
                    stdin=subprocess.DEVNULL,
                    stdout=logf,
                    stderr=logf,
                    preexec_fn=functools.partial(runtime.die_with, os.getpid()),
                )
        except BaseException:  # interrupted while it starts: no worker is left behind
            self.__exit__(None, None, None)
            raise
        return self

    def alive(self) -> None:
        """Raises :class:`WorkerDied` if the worker has exited (so a waiting client does not
        hang); one line, naming its log (its last lines were a page of Celery's output)."""
        if self.proc is not None and self.proc.poll() is not None:
            rc = self.proc.returncode
            if rc == STORE_FULL_EXIT:  # its own log could not be written either
                raise WorkerStoreFull(str(StoreFullError(self.folder)))
            how = f"was killed (signal {-rc})" if rc < 0 else f"exited with code {rc}"
            raise WorkerDied(f"the embedded worker {how}; its log: {self.log}")

    def __exit__(self, *exc) -> None:
        try:
            self._stop()
        finally:
            self._drop_queue(quiet=isinstance(exc[1], WorkerStoreFull) or store_full(exc[1], self.folder))

    def _drop_queue(self, quiet: bool = False) -> None:
        """This run's private queue leaves the broker with its messages (best effort: a
        broker that cannot be written now keeps it, as before). ``quiet``: the run failed
        for a full disk, which its own error says."""
        from workers.app import app

        try:
            with app.connection_for_write() as conn:
                conn.default_channel.queue_delete(self.queue)
        except Exception as e:  # the run's own outcome stands; say why the queue stayed, in one line
            full = store_full(e, self.folder)
            if quiet and full:
                return
            why = "the disk is full" if full else " ".join(str(e).split("\n", 1)[0].split())
            print(f"tween: warning: the embedded broker keeps queue {self.queue}: {why}", file=sys.stderr)

    def _stop(self) -> None:
        if self.proc is None or self.proc.poll() is not None:
            return
        if not (self.cold or self.hurry()):
            # Warm shutdown of the main process (it stops its pool): a client that stops while
            # jobs may still run (an error in its wait) lets them end.
            self.proc.send_signal(signal.SIGTERM)
            deadline = time.monotonic() + WARM_STOP_S
            while time.monotonic() < deadline and not self.hurry():
                try:
                    self.proc.wait(timeout=0.1)
                    return
                except subprocess.TimeoutExpired:
                    pass
        # Its jobs have ended, or its client is told to stop: nothing is left to finish (or its
        # warm shutdown hung).
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.proc.wait()
