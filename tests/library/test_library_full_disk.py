"""A library build on a full disk (a small file-size limit, RLIMIT_FSIZE, in a subprocess): one
line naming the array file, exit 2, and the library byte for byte as it was (an --add had left
the new takes' bytes appended to its arrays), or, for a first build, nothing at all."""

from __future__ import annotations

import os
import resource
import shutil
import signal
import subprocess
import sys
from pathlib import Path

from library_fixtures import BANDAI, HELD_OUT


def _build(args, limit: int, cwd: Path) -> subprocess.CompletedProcess:
    def small_disk():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
    cmd = [sys.executable, "-m", "pipeline.cli", "library", "build", *map(str, args), "--no-progress"]
    return subprocess.run(
        cmd, capture_output=True, text=True, cwd=cwd, env=env, preexec_fn=small_disk, timeout=120
    )


def _full(r: subprocess.CompletedProcess, folder: Path) -> str:
    assert r.returncode == 2, r.stderr[-3000:]
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, r.stderr[-3000:]
    line = r.stderr.strip()
    assert line.startswith(f"tween: error: {folder}/") and ".bin: File too large" in line, line
    return line


def test_an_add_on_a_full_disk_leaves_the_library_byte_for_byte(library, data_dir, tmp_path):
    lib = tmp_path / "lib"
    shutil.copytree(library, lib)
    before = {p.name: p.read_bytes() for p in lib.iterdir()}
    new = tmp_path / "new"
    new.mkdir()
    shutil.copy(data_dir / "bandai_namco" / "dataset-2" / HELD_OUT, new / HELD_OUT)
    # Room for a few frames more in the largest array: the take's fill it up part way.
    limit = max(p.stat().st_size for p in lib.glob("*.bin")) + 1024
    _full(_build([new, "--out", lib, "--add"], limit, tmp_path), lib)
    assert {p.name: p.read_bytes() for p in lib.iterdir()} == before


def test_a_first_build_on_a_full_disk_leaves_nothing(data_dir, tmp_path):
    takes = tmp_path / "takes"
    takes.mkdir()
    shutil.copy(data_dir / "bandai_namco" / "dataset-2" / BANDAI[0], takes / BANDAI[0])
    out = tmp_path / "libs" / "studio"
    _full(_build([takes, "--out", out], 64 * 1024, tmp_path), out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["takes"]  # not even the folders above it


def test_an_add_interrupted_after_its_manifest_keeps_what_it_wrote(library, data_dir, tmp_path):
    """An interrupt after the manifest was written (the farm's last progress call) must not cut
    the arrays back to their sizes before the add: the manifest would name frames they lack."""
    import numpy as np
    import pytest

    from pipeline.library.build import build
    from pipeline.library.store import ARRAYS, open_library, verify

    lib = tmp_path / "lib"
    shutil.copytree(library, lib)
    new = tmp_path / "new"
    new.mkdir()
    shutil.copy(data_dir / "bandai_namco" / "dataset-2" / HELD_OUT, new / HELD_OUT)

    def progress(done, total, name):
        if done == total and not name:  # the call after the commit
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        build(new, lib, add=True, progress=False, on_progress=progress)
    opened = open_library(lib)
    verify(opened)
    frames = opened.manifest["frames"]
    for name, (dtype, shape) in ARRAYS.items():
        size = (lib / f"{name}.bin").stat().st_size
        assert size == frames * int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize, name
    assert any(t["file"].endswith(HELD_OUT) for t in opened.manifest["takes"])
