"""The fill's short-held locks (its shot folder's, a ``--review-layer``'s) held by a hung
writer: the wait ends after ``pipeline.usd.files.LOCK_WAIT_S`` in one line naming the lock
and its holder, exit 2, nothing written (it waited for ever)."""

from __future__ import annotations

import fcntl
import os
import sys
import threading
from contextlib import contextmanager
from pathlib import Path

import pytest
from usd_fixtures import tree_hashes

from pipeline.cli import main

SHOT = Path(__file__).resolve().parents[2] / "examples" / "sh010_walk.usda"
#: A hung writer's lock is let go after this many seconds, so that the code before the bound
#: fails its test (it filled once the lock was free) instead of hanging it.
RELEASE_S = 5.0


@pytest.fixture
def shot(tmp_path, monkeypatch):
    monkeypatch.setattr("pipeline.usd.files.LOCK_WAIT_S", 0.3)
    out = tmp_path / "sh010.usda"
    out.write_bytes(SHOT.read_bytes())
    return out


@contextmanager
def _held(lock: Path, holder: str = "4242@otherhost"):
    """``lock`` held for the block (flock, on an fd of its own: this process's other fd waits
    for it) by a writer that wrote ``holder`` into it, as the fill's writers do; let go after
    RELEASE_S all the same."""
    fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    fcntl.flock(fd, fcntl.LOCK_EX)
    os.write(fd, holder.encode())
    timer = threading.Timer(RELEASE_S, lambda: fcntl.flock(fd, fcntl.LOCK_UN))
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
        timer.join()
        os.close(fd)


def _fill(monkeypatch, capsys, *args) -> tuple[int, str]:
    monkeypatch.setattr(sys, "argv", ["tween", "fill-local", *map(str, args), "--model", "interp"])
    with pytest.raises(SystemExit) as e:
        main()
    return e.value.code or 0, capsys.readouterr().err


def _gave_up(rc: int, err: str, lock: Path, other: str) -> None:
    assert rc == 2, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert lines[-1].startswith(f"tween: error: {lock}: {other} still holds this lock after 0.3 s "), err
    assert "(process 4242@otherhost, since 2" in lines[-1] and lines[-1].endswith(
        "run again once it is done"
    ), err
    assert sum(ln.startswith("tween: error:") for ln in lines) == 1, err


def test_a_shot_folder_lock_held_by_a_hung_writer_ends_the_wait(shot, monkeypatch, capsys):
    lock = shot.parent / ".sh010.tween.lock"
    with _held(lock):
        before = tree_hashes(shot.parent)
        rc, err = _fill(monkeypatch, capsys, shot)
        _gave_up(rc, err, lock, f"another writer of {shot}'s fills")
        assert tree_hashes(shot.parent) == before  # no fill, no review layer; the holder's lock kept


def test_a_review_layer_lock_held_by_a_hung_writer_ends_the_wait(shot, tmp_path, monkeypatch, capsys):
    review = tmp_path / "rev" / "review.usda"
    review.parent.mkdir()
    review.write_text("#usda 1.0\n(\n    subLayers = [\n        @../sh010.usda@\n    ]\n)\n")
    lock = review.parent / ".review.usda.lock"
    with _held(lock):
        before = tree_hashes(tmp_path)
        rc, err = _fill(monkeypatch, capsys, shot, "--review-layer", review)
        _gave_up(rc, err, lock, f"another fill into {review}")
        assert tree_hashes(tmp_path) == before  # the fill layer linked before the review went again
