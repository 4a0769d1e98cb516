"""Running ``tween`` without blocking Blender (no ``bpy``): a subprocess whose output goes to
files, polled by the panel's timer; a fill job from submission to its result.

Nothing here waits: :meth:`FillJob.tick` looks once and returns, so Blender's UI stays
responsive; the modal timer (and a headless caller's loop) calls it again.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

from . import commands
from .status import JobStatus, parse_status


class Run:
    """A subprocess writing to ``<log_dir>/<name>.out`` / ``.err`` (files, not pipes: a
    chatty command never blocks on a full pipe that nobody reads)."""

    def __init__(self, cmd: list[str], env: dict, log_dir: str | Path, name: str, cwd: str | None = None):
        self.cmd = cmd
        log = Path(log_dir)
        log.mkdir(parents=True, exist_ok=True)
        self.out_path, self.err_path = log / f"{name}.out", log / f"{name}.err"
        try:
            with open(self.out_path, "wb") as out, open(self.err_path, "wb") as err:
                self.proc = subprocess.Popen(
                    cmd,
                    env=env,
                    cwd=cwd,
                    stdin=subprocess.DEVNULL,
                    stdout=out,
                    stderr=err,
                    start_new_session=True,
                )
        except OSError as e:
            raise ValueError(f"cannot run {cmd[0]}: {e.strerror or e}") from None

    def poll(self) -> int | None:
        return self.proc.poll()

    def stdout(self) -> str:
        return self.out_path.read_text(errors="replace") if self.out_path.exists() else ""

    def stderr(self) -> str:
        return self.err_path.read_text(errors="replace") if self.err_path.exists() else ""

    def error(self) -> str:
        return commands.error_line(self.stderr(), self.stdout(), self.poll())

    def interrupt(self) -> None:
        """SIGINT, as Ctrl-C: ``tween fill`` then cancels its jobs and undoes their work."""
        if self.proc.poll() is None:
            try:
                os.kill(self.proc.pid, signal.SIGINT)
            except ProcessLookupError:
                pass


class FillJob:
    """One Fill: the ``tween fill``/``tween submit`` process, then ``tween status`` polls.

    ``state``: ``starting`` (no job id yet), ``running``, ``done`` (``result`` is the
    fill's JSON), ``failed`` (``error`` is one line).
    """

    def __init__(
        self, settings: commands.Settings, shot: str, out_dir: str, log_dir: str, interval: float = 1.0
    ):
        self.settings, self.shot, self.out_dir, self.log_dir = settings, shot, out_dir, log_dir
        self.interval = interval
        self.env = commands.environment(settings)
        self.state, self.job_id, self.error = "starting", None, None
        self.status: JobStatus | None = None
        self.result: dict | None = None
        self._poll: Run | None = None
        self._polled_at = 0.0
        self._n = 0
        stamp = time.strftime("%Y%m%d-%H%M%S")
        self.name = f"fill-{stamp}-{os.getpid()}"
        self.proc = Run(commands.fill_command(settings, shot, out_dir), self.env, log_dir, self.name)

    @property
    def finished(self) -> bool:
        return self.state in ("done", "failed")

    def text(self) -> str:
        if self.state == "starting":
            return "submitting"
        if self.state == "failed":
            return f"failed: {self.error}"
        return self.status.text() if self.status else "submitted"

    @property
    def fraction(self) -> float:
        return self.status.fraction if self.status else 0.0

    def _fail(self, line: str) -> None:
        self.state, self.error = "failed", line

    def tick(self) -> str:
        """One look (never waits); returns the state."""
        if self.finished:
            return self.state
        rc = self.proc.poll()
        if self.job_id is None:
            if self.settings.farm == "FARM":
                if rc is None:
                    return self.state
                ids = commands.submitted_ids(self.proc.stdout())
                if rc != 0 or not ids:
                    self._fail(self.proc.error())
                    return self.state
                self.job_id = ids[0]
            else:
                self.job_id = commands.submitted_id(self.proc.stderr())
                if self.job_id is None:
                    if rc is not None:  # it ended before it submitted: a bad shot or option
                        self._fail(self.proc.error())
                    return self.state
            self.state = "running"
        self._status(rc)
        return self.state

    def _status(self, rc: int | None) -> None:
        if self._poll is None:
            if time.monotonic() - self._polled_at < self.interval:
                return
            self._n += 1
            cmd = commands.status_command(self.settings, self.job_id)
            self._poll = Run(cmd, self.env, self.log_dir, f"{self.name}.status{self._n % 2}")
            return
        if self._poll.poll() is None:
            return
        poll, self._poll, self._polled_at = self._poll, None, time.monotonic()
        try:
            st = parse_status(poll.stdout(), self.job_id)
        except ValueError:
            if poll.poll() != 0:  # the farm cannot be asked (broker down, bad settings)
                self._fail(poll.error())
            return
        self.status = st
        if st.state == "SUCCESS":
            self.state, self.result = "done", st.result
        elif st.finished:
            self._fail(st.error or f"job {self.job_id} {st.state.lower()}")
        elif rc is not None and rc != 0 and self.settings.farm == "EMBEDDED":
            self._fail(self.proc.error())  # the embedded farm stopped with its job unfinished

    def cancel(self) -> None:
        """Embedded: interrupts ``tween fill`` (it cancels its jobs and undoes them); farm:
        ``tween cancel`` (started, not waited for)."""
        if self.settings.farm == "EMBEDDED":
            self.proc.interrupt()
        elif self.job_id:
            cmd = [commands.executable(self.settings) or self.settings.tween, "cancel", self.job_id]
            Run(cmd, self.env, self.log_dir, f"{self.name}.cancel")
        self._fail("cancelled")


class Command:
    """A short ``tween`` command (approve, publish, review) run the same way; ``tick()``
    returns None while it runs, then (ok, stdout, one error line)."""

    def __init__(self, cmd: list[str], settings: commands.Settings, log_dir: str, name: str):
        self.what = name
        self.on_done = None  # called with stdout once it succeeded; returns the report line
        self.run = Run(
            cmd, commands.environment(settings), log_dir, f"{name}-{time.strftime('%Y%m%d-%H%M%S')}"
        )

    def tick(self) -> tuple[bool, str, str] | None:
        rc = self.run.poll()
        if rc is None:
            return None
        return rc == 0, self.run.stdout(), "" if rc == 0 else self.run.error()
