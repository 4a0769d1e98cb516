"""`tween bench` on a full disk (a small file-size limit, RLIMIT_FSIZE, in a subprocess): one
line naming the file, exit 2, and an earlier run's results kept whole (bench.json was cut to
the limit, invalid JSON), a first run's folder not made at all (a bench.json and an empty
bench.md were left)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

#: The protocol bench on three windows of zeros with made-up metrics, under a 512-byte limit
#: (its bench.json is about 1 kB).
SCRIPT = """
import resource, signal, sys
import numpy as np
import pipeline.bench.run as run
from pipeline.cli import main

fake = {t: {m: 1.0 for m in run.METRICS} | {"skate_gt": 0.0} for t in run.TRANSITIONS}
run.test_windows = lambda *a: (np.zeros((3, 65, 1, 4)), np.zeros((3, 65, 3)))
run.load_split = lambda name: None
run.position_stats = lambda train: (None, None)
run.evaluate = lambda *a: fake
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
resource.setrlimit(resource.RLIMIT_FSIZE, (512, 512))
main(["bench", "--methods", "zero", *sys.argv[1:]])
"""


def _bench(*args, cwd: Path) -> str:
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
    r = subprocess.run([sys.executable, "-c", SCRIPT, *map(str, args)], capture_output=True, text=True,
                       cwd=cwd, env=env, timeout=120)  # fmt: skip
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith("tween:")]
    assert r.returncode == 2 and len(errors) == 1 and "Traceback" not in r.stderr, r.stderr[-3000:]
    return errors[0]


def test_a_rerun_on_a_full_disk_keeps_the_earlier_results(tmp_path):
    out = tmp_path / "bench"
    out.mkdir()
    (out / "bench.json").write_text('{"earlier": 1}')
    (out / "bench.md").write_text("earlier\n")
    line = _bench("--out", out, "--force", cwd=tmp_path)
    assert line == f"tween: error: {out / 'bench.json'}: File too large", line
    assert sorted(p.name for p in out.iterdir()) == ["bench.json", "bench.md"]  # no temporaries
    assert (out / "bench.json").read_text() == '{"earlier": 1}' and (
        out / "bench.md"
    ).read_text() == "earlier\n"


def test_a_first_run_on_a_full_disk_leaves_nothing(tmp_path):
    out = tmp_path / "results" / "bench"
    line = _bench("--out", out, cwd=tmp_path)
    assert line == f"tween: error: {out / 'bench.json'}: File too large", line
    assert list(tmp_path.iterdir()) == []
