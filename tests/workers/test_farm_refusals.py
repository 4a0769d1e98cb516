"""Farm commands refuse what they cannot run in one line, exit 2, before any farm is reached:
shots that are not files or are given twice, job ids that cannot be ids, worker options
Celery would fail on later. (The broker named here does not answer: none is contacted.)"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
NOWHERE = "redis://127.0.0.1:1/0"  # a port nothing listens on


def _tween(tmp_path: Path, *args: str, broker: str | None = NOWHERE):
    env = {k: v for k, v in os.environ.items() if not k.startswith("TWEEN_")}
    env.update(TWEEN_FARM_CONFIG=os.devnull, TWEEN_CACHE=str(tmp_path / "cache"))
    if broker:
        env["TWEEN_BROKER_URL"] = broker
    cmd = [sys.executable, "-m", "pipeline.cli", *args]
    return subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)


@pytest.fixture
def shot(tmp_path) -> Path:
    p = tmp_path / "sh010.usda"
    shutil.copy(REPO / "examples" / "sh010_walk.usda", p)
    return p


def _refused(res, says: str) -> None:
    assert res.returncode == 2 and res.stdout == "", res.stderr
    assert res.stderr.count("\n") == 1 and res.stderr.startswith("tween: error: "), res.stderr
    assert says in res.stderr, res.stderr


def test_submit_refuses_a_missing_shot_or_a_folder_before_sending(tmp_path, shot):
    """Both exited 0 with a job id, whose job then failed on the farm ("file not found")."""
    _refused(_tween(tmp_path, "submit", "nosuch.usda"), "nosuch.usda: file not found")
    _refused(_tween(tmp_path, "submit", str(shot), "."), ".: a folder, not a shot file")


def test_a_shot_that_is_a_pipe_or_a_link_to_nothing_is_named_as_such(tmp_path, shot):
    """Both were "no such shot file", though the path is there."""
    os.mkfifo(tmp_path / "pipe.usda")
    (tmp_path / "gone.usda").symlink_to(tmp_path / "nowhere.usda")
    _refused(
        _tween(tmp_path, "submit", "pipe.usda"),
        "pipe.usda: not a regular file (a pipe, socket or device), not a shot file",
    )
    _refused(_tween(tmp_path, "submit", str(shot), "gone.usda"), "gone.usda: a link to nothing")


def test_a_shot_given_twice_is_refused(tmp_path, shot):
    """`tween fill x.usda ./d/../x.usda` made two versions of one shot in one run."""
    (tmp_path / "d").mkdir()
    again = f"d/../{shot.name}"
    for cmd in ("fill", "submit"):
        res = _tween(tmp_path, cmd, shot.name, again, broker=None if cmd == "fill" else NOWHERE)
        _refused(res, f"{again}: the same shot as {shot.name} (give each shot once)")
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "cache") == ["d", "sh010.usda"]


@pytest.mark.parametrize("cmd", ["status", "cancel"])
@pytest.mark.parametrize("job", ["", " ", "abc\ndef"])
def test_a_job_id_that_cannot_be_one_is_one_line(tmp_path, cmd, job):
    """An empty id was an internal error on Redis (ValueError: task_id must not be empty); one
    with a newline a two-line error."""
    _refused(_tween(tmp_path, cmd, job), f"job id {job!r}: not a job id")


@pytest.mark.parametrize(
    "args, says",
    [
        (["--include", "no.such.module"], "--include 'no.such.module': no such module"),
        (["-n", "node%z"], "--hostname 'node%z': Unknown format %z"),
        (["--queue", ""], "--queue '': empty"),
    ],
)
def test_worker_options_celery_would_fail_on_are_one_line(tmp_path, args, says):
    """A module that is not there and a name with an unknown %-format were internal errors
    from Celery's worker; an empty queue a worker that never ran a job."""
    _refused(_tween(tmp_path, "worker", "-c", "1", *args), says)


@pytest.mark.parametrize("store, cmd", [("broker.sqlite", "fill"), ("results.sqlite", "status")])
def test_a_damaged_embedded_store_is_one_line_naming_it(tmp_path, shot, store, cmd):
    """Garbage in the embedded farm's SQLite broker or result store was an internal error
    (DatabaseError: file is not a database) after a three-line warning."""
    farm = tmp_path / "cache" / "farm"
    farm.mkdir(parents=True)
    (farm / store).write_text("garbage\n")
    res = _tween(tmp_path, cmd, shot.name if cmd == "fill" else "abc", broker=None)
    _refused(res, f"{farm.resolve() / store}: the embedded farm's ")
    assert "is damaged (not an SQLite database)" in res.stderr
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "cache") == ["sh010.usda"]


def test_submit_train_rig_of_a_folder_says_so(tmp_path):
    """A folder given as the clip said "no such file"."""
    (tmp_path / "clips").mkdir()
    _refused(_tween(tmp_path, "submit-train-rig", "clips", "--out", "m"), "clips: a folder, not a clip file")
    os.mkfifo(tmp_path / "pipe.bvh")  # said "no such file" too, in other words than every reader's
    _refused(_tween(tmp_path, "submit-train-rig", "pipe.bvh", "--out", "m"),
             "pipe.bvh: not a regular file (a pipe, socket or device), not a clip file")  # fmt: skip
    _refused(_tween(tmp_path, "submit-train-rig", "none.bvh", "--out", "m"), "none.bvh: file not found")
