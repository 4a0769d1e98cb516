"""`tween export` reads what it is given as bounded as the rest: the model.json of the model a
run was initialised from (whose licence it inherits) through the one reader (before: a pipe
there blocked the export for ever, a link to /dev/zero read until memory ran out, deep JSON
was a RecursionError's traceback), and the run's checkpoint config sized on the meta device
first, as `tween train --init` does (before: a config of 1,000 levels or a DNA of 10^6 built
the network it describes, gigabytes, before comparing its weights)."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import asdict
from pathlib import Path

import pytest
from damaged_inputs import replace_with

torch = pytest.importorskip("torch")

from pipeline.networks.generator import Generator, GeneratorConfig  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
#: The address space the export runs in: several times what a refusal needs (torch alone maps
#: ~0.7 GiB), far below what the configs below asked for.
LIMIT = 3 << 30
CHILD = """
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, (int(sys.argv[1]), int(sys.argv[1])))
from pipeline.cli import main
try:
    main(sys.argv[2:])
finally:  # VmHWM: this process's own peak (ru_maxrss may carry the forking parent's)
    status = open("/proc/self/status").read().split("VmHWM:")[1].split()
    print(int(status[0]) * 1024, flush=True)
"""
SMALL = GeneratorConfig(width=8, levels=(8, 8), bottleneck_dilations=(1,))


def _run(tmp_path: Path, config: dict, weights=None) -> Path:
    """A run folder whose generator.pt holds ``weights`` (the small network's) and ``config``."""
    run = tmp_path / "run"
    run.mkdir()
    state = {"model": weights or Generator(SMALL).state_dict(), "config": config, "step": 4, "elapsed": 1.0}
    torch.save(state, run / "generator.pt")
    return run


def _export(run: Path, out: Path) -> tuple[str, int]:
    """``tween export RUN --out OUT`` in a process of at most LIMIT bytes: (its one error line,
    its peak resident memory); fails the test where it exits otherwise or takes over 2 minutes."""
    r = subprocess.run(
        [sys.executable, "-c", CHILD, str(LIMIT), "export", str(run), "--out", str(out)],
        capture_output=True, text=True, timeout=120, cwd=ROOT,
    )  # fmt: skip
    assert r.returncode == 2, f"exit {r.returncode}: {r.stderr[-3000:]}"
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("tween: error: "), r.stderr[-3000:]
    assert not out.exists() and not list(out.parent.glob(f".{out.name}*")), "a partial model was left"
    return lines[0], int(r.stdout.split()[-1])


@pytest.mark.parametrize("how", ["fifo", "zero", "deep"])
def test_the_init_models_json_is_read_by_the_one_reader(tmp_path, how):
    init = tmp_path / "init_model"
    init.mkdir()
    card = init / "model.json"
    replace_with(card, how)
    run = _run(tmp_path, {"model": asdict(SMALL), "init": str(init)})
    line, _ = _export(run, tmp_path / "new")
    assert line.startswith(f"tween: error: {card}: "), line
    want = "nested too deeply" if how == "deep" else "not a regular file (a pipe, socket or device)"
    assert want in line, line


@pytest.mark.parametrize(
    "model, why",
    [
        ({"dna": 10**6}, "its config describes a network of "),  # no DNA weights to compare with
        ({"levels": [256] * 1000}, "its config describes a network of over 32 layers"),
    ],
    ids=["dna", "levels"],
)
def test_a_run_whose_config_asks_for_a_huge_network_is_refused_before_it_is_built(tmp_path, model, why):
    run = _run(tmp_path, {"model": {**asdict(SMALL), **model}})
    line, peak = _export(run, tmp_path / "new")
    assert line.startswith(f"tween: error: {run / 'generator.pt'}: the run's checkpoint: {why}"), line
    if model.get("dna"):
        assert "weights (at most 500,000,000)" in line, line
    assert peak < 1 << 30, f"peak resident memory {peak / 2**20:.0f} MiB"


def test_an_init_models_licence_is_still_inherited_and_a_run_folder_states_none(tmp_path):
    from pipeline.train.export import data_terms

    terms = data_terms({"init": str(ROOT / "models" / "default")})
    inherited = [s for s in terms["sources"] if s["use"].startswith("inherited")]
    assert inherited[0]["name"] == "tween-bandai-v5.3" and inherited[0]["licence"] == "CC BY-NC 4.0"
    run = _run(tmp_path, {"model": asdict(SMALL)})  # a run folder holds no model.json
    terms = data_terms({"init": str(run / "generator.pt")})
    assert terms["sources"][-1] == {
        "name": str(run / "generator.pt"), "licence": "not stated", "use": "inherited: initialised from it"
    }  # fmt: skip


def test_a_run_whose_path_predictor_config_asks_for_a_huge_network_is_refused_before_it_is_built(tmp_path):
    from pipeline.networks.path import PathConfig, PathPredictor

    run = _run(tmp_path, {"model": asdict(SMALL)})
    config = {"model": {"n_joints": 21, "channels": [3000, 3000]}}  # 614 million weights: 2.4 GB
    state = {"model": PathPredictor(PathConfig()).state_dict(), "config": config, "step": 4, "elapsed": 1.0}
    torch.save(state, run / "path.pt")
    line, peak = _export(run, tmp_path / "new")
    assert line.startswith(
        f"tween: error: {run / 'path.pt'}: the run's checkpoint: its weights are not those of the network"
    ), line
    assert peak < 1 << 30, f"peak resident memory {peak / 2**20:.0f} MiB"
