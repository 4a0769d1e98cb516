"""`tween fill` on a farm where no worker takes its queue says so, once, on stderr, and keeps
waiting (a worker may yet start); Ctrl-C cancels the queued job as ever."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time

from redis_server import copy_shot, example_shot, farm_env, start_redis

from workers import cli, jobs
from workers.jobs import JobState

NOTICE = "tween: no worker takes the farm's queue {!r} (start one: `tween worker`); the job(s) wait there, Ctrl-C cancels them"


def _lines_until(proc, text: str, timeout: float) -> list[str]:
    """stderr lines of ``proc`` up to and including the first holding ``text``."""
    lines, t0 = [], time.monotonic()
    while not lines or text not in lines[-1]:
        left = timeout - (time.monotonic() - t0)
        assert left > 0 and proc.poll() is None, "".join(lines)[-3000:]
        if select.select([proc.stderr], [], [], min(left, 1.0))[0]:
            lines.append(proc.stderr.readline())
    return lines


def test_a_fill_no_worker_takes_says_so_once_and_ctrl_c_cancels_it(tmp_path):
    server = start_redis()
    try:
        root = tmp_path / "shots"
        shot = copy_shot(example_shot(), root, "idle")
        env = {k: v for k, v in os.environ.items() if not k.startswith("TWEEN_")}
        env.update(farm_env(server, [str(root)]))
        cmd = [sys.executable, "-m", "pipeline.cli", "fill", str(shot), "--no-progress"]
        proc = subprocess.Popen(
            cmd, env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        try:
            t0 = time.monotonic()
            before = _lines_until(proc, "no worker takes", timeout=60)
            waited = time.monotonic() - t0
            time.sleep(cli.IDLE_CHECK_S / 2)
            assert proc.poll() is None  # still waiting for a worker
            proc.send_signal(signal.SIGINT)
            out, after = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
        err = "".join(before) + after
        assert waited >= cli.IDLE_CHECK_S - 1  # asked once the jobs had sat queued that long
        assert [line for line in err.splitlines() if "no worker" in line] == [
            NOTICE.format(env["TWEEN_QUEUE"])
        ]
        assert proc.returncode == 130 and out == "", err[-3000:]
        assert "cancelled" in err
        assert sorted(p.name for p in root.iterdir()) == ["idle.usda"]  # nothing of the job kept
    finally:
        server.cleanup()


def test_the_notice_asks_once_and_only_while_every_job_is_queued(monkeypatch, capsys):
    monkeypatch.setattr(cli, "IDLE_CHECK_S", 0.0)
    states = {"a": JobState(id="a", state="QUEUED", record={"queue": "q"})}
    asked = []
    monkeypatch.setattr(jobs, "state", lambda j: states[j])
    monkeypatch.setattr(jobs, "unserved_queues", lambda qs: asked.append(sorted(qs)) or sorted(qs))
    notice = cli._NoWorkerNotice(["a"])
    notice()
    notice()
    assert asked == [["q"]]
    assert capsys.readouterr().err == NOTICE.format("q") + "\n"
    # A worker takes the queue: nothing said.
    monkeypatch.setattr(jobs, "unserved_queues", lambda qs: [])
    cli._NoWorkerNotice(["a"])()
    assert capsys.readouterr().err == ""
    # A job already running (or done in part): a worker exists, nothing asked.
    states["a"] = JobState(id="a", state="RUNNING", record={"queue": "q"})
    asked.clear()
    monkeypatch.setattr(jobs, "unserved_queues", lambda qs: asked.append(qs) or ["q"])
    cli._NoWorkerNotice(["a"])()
    assert asked == [] and capsys.readouterr().err == ""
    # The farm cannot be asked: the wait goes on, its own errors come through it.
    states["a"] = JobState(id="a", state="QUEUED", record={"queue": "q"})

    def down(qs):
        raise ConnectionError("broker gone")

    monkeypatch.setattr(jobs, "unserved_queues", down)
    cli._NoWorkerNotice(["a"])()
    assert capsys.readouterr().err == ""
