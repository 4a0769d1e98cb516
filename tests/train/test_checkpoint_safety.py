"""Checkpoints are read with torch.load(weights_only=True): before, a crafted generator.pt or
train-rig state.pt ran its pickled code (os.system) when `tween train --init`, `tween export`
or `tween train-rig` read it. And an --init config of an absurd size is refused before its
network is built (before: width 10**6 allocated gigabytes, then died of the allocator)."""

from __future__ import annotations

import os
from dataclasses import asdict, replace
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")

from pipeline.errors import TweenError  # noqa: E402
from pipeline.networks.generator import Generator, GeneratorConfig  # noqa: E402
from pipeline.train.generator_training import (  # noqa: E402
    TrainConfig,
    _with_init,
    load_init,
    read_checkpoint,
)

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = sorted(ROOT.glob("models/*/torch/*.pt"))


class _Evil:
    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def _evil(tmp_path: Path, name="generator.pt", **state) -> tuple[Path, Path]:
    marker = tmp_path / "PWNED"
    path = tmp_path / name
    torch.save({**state, "step": _Evil(marker)}, path)
    return path, marker


def _memory(field: str) -> int:
    """A field of /proc/self/status in bytes (VmRSS: resident now, VmHWM: peak): torch's
    allocations are not Python's, tracemalloc does not see them."""
    status = Path("/proc/self/status").read_text()
    return int(next(x for x in status.splitlines() if x.startswith(field + ":")).split()[1]) * 1024


def _small_checkpoint() -> dict:
    return {"model": {"w": torch.zeros(2)}, "config": {"model": {}}}


def test_a_crafted_generator_checkpoint_runs_no_code(tmp_path):
    path, marker = _evil(tmp_path, **_small_checkpoint())
    with pytest.raises(TweenError) as e:
        load_init(str(path))
    assert str(e.value).startswith(
        f"{path}: --init: holds something other than tensors and plain values and was refused for safety"
    )
    assert "\n" not in str(e.value)
    with pytest.raises(TweenError, match="the run's checkpoint"):
        read_checkpoint(path, "the run's checkpoint")
    assert not marker.exists()


def test_a_crafted_rig_state_runs_no_code(tmp_path):
    from pipeline.rig.train import Trainer, TrainError

    path, marker = _evil(tmp_path, name="state.pt")
    bare = type("Bare", (Trainer,), {"ckpt_dir": tmp_path, "device": torch.device("cpu")})
    trainer = bare.__new__(bare)  # only what _read_state reads
    with pytest.raises(TrainError, match="refused for safety"):
        trainer._read_state(path)
    assert not marker.exists()


@pytest.mark.skipif(not SHIPPED, reason="no shipped checkpoints")
@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: f"{p.parent.parent.name}/{p.name}")
def test_the_shipped_checkpoints_load_whole(path):
    state = read_checkpoint(path, "--init", config=False)
    full = torch.load(path, weights_only=False, map_location="cpu")  # our own files: trusted
    _same(state, full)


def _same(a, b) -> None:
    assert type(a) is type(b), (type(a), type(b))
    if isinstance(a, torch.Tensor):
        assert a.dtype == b.dtype and torch.equal(a, b)
    elif isinstance(a, dict):
        assert a.keys() == b.keys()
        for k in a:
            _same(a[k], b[k])
    elif isinstance(a, list | tuple):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _same(x, y)
    else:
        assert a == b


@pytest.mark.skipif(not (ROOT / "models/default/torch/generator.pt").exists(), reason="no default model")
def test_the_default_model_is_an_init():
    cfg, init = _with_init(TrainConfig(init=str(ROOT / "models/default")), torch.device("cpu"))
    assert init is not None and cfg.model.width > 0


@pytest.mark.parametrize(
    "model, why",
    [
        ({"width": 10**6}, "its weights are not those of the network its config describes"),
        ({"dna": 10**6}, "weights (at most 500,000,000)"),  # no DNA weights to compare with
        ({"levels": [256] * 1000}, "over 32 layers"),
    ],
    ids=["width", "dna", "levels"],
)
def test_an_init_config_of_a_huge_network_is_refused_without_building_it(tmp_path, model, why):
    small = GeneratorConfig(width=8, levels=(8, 8), bottleneck_dilations=(1,))
    weights = Generator(small).state_dict()
    state = {"model": weights, "config": {"model": {**asdict(small), **model}}}
    path = tmp_path / "generator.pt"
    torch.save(state, path)
    Path("/proc/self/clear_refs").write_text("5")  # the peak starts again from here
    base = _memory("VmRSS")
    with pytest.raises(TweenError) as e:
        _with_init(replace(TrainConfig(), init=str(path)), torch.device("cpu"))
    peak = _memory("VmHWM") - base
    assert str(e.value).startswith(f"{path}: --init: ") and why in str(e.value), e.value
    assert "\n" not in str(e.value)
    assert peak < 200 * 2**20, peak


def test_a_damaged_log_line_is_not_a_step():
    """Before: a deeply nested line (a damaged train_log.jsonl) raised RecursionError when a
    run resumed, and {"step": true} counted as step 1."""
    from pipeline.train.generator_training import _logged_step

    assert _logged_step(b"[" * 100_000 + b"\n") is None
    assert _logged_step(b'{"step": true}\n') is None
    assert _logged_step(b'{"step": 3}\n') == 3


def test_a_text_file_is_damaged_not_refused_for_safety(tmp_path):
    """A file whose first byte is ``c`` reads as pickle's GLOBAL opcode, and torch's error
    named a "global": a text file was said to be refused for safety. Only a torch checkpoint
    (a zip) whose pickle names code is that; this is not a checkpoint."""
    path = tmp_path / "generator.pt"
    path.write_text("config: lr=0.1\nsteps: 100\n")
    with pytest.raises(TweenError) as e:
        load_init(str(path))
    assert "not a checkpoint that `tween train` wrote" in str(e.value), str(e.value)
    assert "safety" not in str(e.value)
