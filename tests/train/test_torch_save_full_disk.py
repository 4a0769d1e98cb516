"""Checkpoints and exported weights on a full disk (a small file-size limit, RLIMIT_FSIZE, in a
subprocess): torch.save's own writer raised RuntimeError ("unexpected pos"), an internal error
with exit 1, and train-rig left its half-written state.pt.tmp; now one line naming the file,
exit 2, no temporary, and a checkpoint written before kept whole."""

from __future__ import annotations

import os
import re
import resource
import signal
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("torch")

ROOT = Path(__file__).resolve().parents[2]
LIMIT = 1024 * 1024  # bytes: the data cache of one clip fits, no checkpoint does


def _small_disk():
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
    resource.setrlimit(resource.RLIMIT_FSIZE, (LIMIT, LIMIT))


def _run(args, cwd: Path) -> str:
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1", "OMP_NUM_THREADS": "1"}
    r = subprocess.run([sys.executable, *map(str, args)], capture_output=True, text=True, cwd=cwd, env=env,
                       preexec_fn=_small_disk, timeout=120)  # fmt: skip
    errors = re.findall(r"tween: [^\r\n]*", r.stderr)  # (after a progress bar's last draw)
    assert r.returncode == 2 and len(errors) == 1 and "Traceback" not in r.stderr, r.stderr[-3000:]
    return errors[0]


def test_save_torch_keeps_the_earlier_file_and_names_its_own(tmp_path):
    path = tmp_path / "state.pt"
    path.write_bytes(b"the earlier checkpoint")
    code = (
        "import errno, sys, torch\nfrom pipeline.atomic import save_torch\n"
        "try:\n    save_torch({'w': torch.zeros(1 << 20)}, sys.argv[1])\n"
        "except OSError as e:\n    assert e.errno == errno.EFBIG, e\n    print(f'tween: {e.filename}', file=sys.stderr)\n"
        "    sys.exit(2)\n"
    )
    assert _run(["-c", code, path], tmp_path) == f"tween: {path}"
    assert path.read_bytes() == b"the earlier checkpoint" and os.listdir(tmp_path) == ["state.pt"]


def test_train_on_a_full_disk_is_one_line_naming_the_checkpoint(tmp_path):
    run = tmp_path / "run"
    tiny = ["--steps", "4", "--path-steps", "0", "--batch", "2", "--lengths", "64", "--limit-clips", "1"]
    line = _run(["-m", "pipeline.cli", "train", "--out", run, *tiny, "--threads", "1"], tmp_path)
    assert line == f"tween: error: {run / 'generator.pt'}: File too large", line
    assert sorted(os.listdir(run)) == ["train_log.jsonl"]  # no temporary


def test_train_rig_on_a_full_disk_is_one_line_naming_the_checkpoint(tmp_path, bandai_clip):
    out = tmp_path / "model"
    args = ["--schedule", "tiny", "--iters", "2", "--frames", "0:60", "--threads", "1"]
    line = _run(["-m", "pipeline.cli", "train-rig", bandai_clip, "--out", out, *args], tmp_path)
    state = tmp_path / ".model.partial" / "checkpoints" / "state.pt"
    assert line == f"tween: error: {state}: File too large", line
    assert sorted(os.listdir(state.parent)) == ["train_config.json"]  # no state.pt.tmp of 8 MB


def test_every_torch_save_goes_through_save_torch():
    """The fix above holds only where torch.save writes to memory (pipeline.atomic.save_torch)."""
    hits = [f"{p.relative_to(ROOT)}:{n}" for p in sorted((ROOT / "pipeline").rglob("*.py"))
            for n, line in enumerate(p.read_text().splitlines(), 1)
            if re.search(r"\btorch\.save\(", line) and p.name != "atomic.py"]  # fmt: skip
    assert not hits, hits


def test_export_on_a_full_disk_names_the_out_folder(tmp_path):
    """Not the hidden folder the model is made in; the ONNX writer's error named no file."""
    run, out = tmp_path / "run", tmp_path / "model"
    tiny = ["--steps", "4", "--path-steps", "0", "--batch", "2", "--lengths", "64", "--limit-clips", "1"]
    train = [sys.executable, "-m", "pipeline.cli", "train", "--out", run, *tiny, "--threads", "1"]
    subprocess.run(train, check=True, capture_output=True, timeout=120)
    line = _run(["-m", "pipeline.cli", "export", run, "--out", out], tmp_path)
    assert (
        line
        == f"tween: error: {out}: cannot write the new model's generator.onnx: File too large; --out is as it was"
    )
    assert sorted(os.listdir(tmp_path)) == ["run"]
