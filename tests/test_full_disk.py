"""A disk that fills up mid-write, simulated with a small file-size limit (RLIMIT_FSIZE): each
command that writes says so in one line and leaves nothing partial where its output goes."""

from __future__ import annotations

import os
import resource
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LIMIT = 64 * 1024  # bytes: more than a log line, less than any shot, layer or frame


def _small_disk():
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
    resource.setrlimit(resource.RLIMIT_FSIZE, (LIMIT, LIMIT))


def _tween(*args, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "TWEEN_FARM_CONFIG": os.devnull, "PYTHONDONTWRITEBYTECODE": "1"}
    return subprocess.run([sys.executable, "-m", "pipeline.cli", *map(str, args)], capture_output=True,
                          text=True, cwd=cwd, env=env, preexec_fn=_small_disk, timeout=300)  # fmt: skip


@pytest.fixture
def shot(tmp_path) -> Path:
    s = tmp_path / "shots" / "sh010.usda"
    s.parent.mkdir()
    shutil.copy(ROOT / "examples" / "sh010_walk.usda", s)
    return s


def _refused_for_space(r: subprocess.CompletedProcess) -> str:
    last = r.stderr.rstrip("\n").rsplit("\n", 1)[-1]
    assert r.returncode == 2, r.stderr[-3000:]
    assert last.startswith("tween: error: ") and "file too large" in last.lower(), r.stderr[-3000:]
    assert "Traceback" not in r.stderr and r.stderr.count("tween: error:") == 1
    return last


def test_convert_to_a_full_disk(tmp_path, bandai_clip):
    out = tmp_path / "out"
    out.mkdir()
    line = _refused_for_space(_tween("convert", bandai_clip, out / "sh020.usda", cwd=tmp_path))
    assert str(out / "sh020.usda") in line
    assert list(out.iterdir()) == []


def test_fill_to_a_full_disk(tmp_path, shot):
    before = sorted(shot.parent.iterdir())
    _refused_for_space(_tween("fill-local", shot, "--out", tmp_path / "fills", cwd=tmp_path))
    assert not (tmp_path / "fills").exists() and sorted(shot.parent.iterdir()) == before


def test_review_to_a_full_disk(tmp_path, shot):
    _refused_for_space(_tween("review", shot, "-o", tmp_path / "review", cwd=tmp_path))
    assert not (tmp_path / "review").exists() or list((tmp_path / "review").rglob("*")) == []
