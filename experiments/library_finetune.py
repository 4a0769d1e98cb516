"""A studio's fine-tune beside its library, split by take: the library bench's CMU split (every
fifth take of each subject held out), a network fine-tuned on the library's takes as a studio
would (`tween train --data TAKES --init MODEL`, then `tween export`), and the held-out takes
filled through the product path with the library and that network probed beside it
(`python -m pipeline.bench.library --source cmu --model OUT/model`). Offline study (issue 30,
item 3; docs/library.md, A studio's own network beside its library).

``python experiments/library_finetune.py OUT [--init models/delta] [--steps 1000] [--threads 2]``;
``--reuse`` skips the training where OUT already holds the run's checkpoint.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

from pipeline.bench.library import run, split
from pipeline.bench.report import publish

#: The fine-tune's settings: recipes/tween-cmu-s123-delta-ft.toml's stage, its step count aside.
TRAIN_ARGS = ("--path-steps 0 --batch 64 --lr 2e-4 --curriculum 0 --pos-zscore --gap-weighting 1.0 "
              "--adv-start -1 --mirror 0.5 --seed 21").split()  # fmt: skip


def takes_folder(out: Path) -> Path:
    """OUT/takes: links to the library takes of the bench's CMU split (none held out)."""
    lib, held = split("cmu")
    folder = out / "takes"
    folder.mkdir(parents=True, exist_ok=True)
    for f in lib:
        link = folder / f.name
        if not link.exists():
            link.symlink_to(f.resolve())
    leaked = {f.name for f in held} & {p.name for p in folder.iterdir()}
    if leaked:  # an OUT of an earlier split: never tune on a held-out take
        raise SystemExit(f"{folder}: holds held-out takes {sorted(leaked)}; use a new OUT")
    return folder


def tween(*args) -> None:
    cmd = [sys.executable, "-m", "pipeline.cli", *map(str, args)]
    print("library_finetune:", " ".join(cmd[2:]), file=sys.stderr)
    subprocess.run(cmd, check=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="folder for the takes' links, the run, the model and library.json")
    ap.add_argument("--init", default="models/delta", help="the network the fine-tune starts from")
    ap.add_argument("--steps", type=int, default=1000, help="generator steps")
    ap.add_argument("--threads", type=int, default=2, help="torch threads")
    ap.add_argument("--reuse", action="store_true", help="keep a run OUT already holds")
    a = ap.parse_args(argv)
    takes = takes_folder(a.out)
    runs = a.out / "run"
    if not (a.reuse and (runs / "generator.pt").exists()):
        tween("train", "--data", takes, "--init", a.init, "--out", runs, "--steps", a.steps,
              "--threads", a.threads, *TRAIN_ARGS)  # fmt: skip
    model = a.out / "model"
    tween("export", runs, "--out", model, "--name", f"studio-cmu-bytake-{Path(a.init).name}", "--force")
    rep = run(("cmu",), methods=("library", "library-alone", "default", "spline"), model=str(model))
    rep["fine_tune"] = {"init": a.init, "steps": a.steps, "args": list(TRAIN_ARGS), "takes": str(takes)}
    publish(rep, a.out, "library")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
