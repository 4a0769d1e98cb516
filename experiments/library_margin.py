"""The probe margin of a small library shipped beside the network, chosen on a tuning split
that holds neither the other-actor bench's subjects (CMU 5-7) nor Bandai's eval split.

Tuning takes: each of CMU subjects 1, 2 and 3 held out in turn from a library of the other two
(other actors, as a shipped library meets them), and the Bandai dataset-2 train takes numbered
3 mod 5 (every ``--bandai-stride``-th) against the library of CMU 1-3 (the studio's own kind of
motion, which the network was trained on, so the network's side there is optimistic and the
margin errs towards the network). Per take: the library trusted against the spline only, the
network trusted, the spline, and both in-betweeners' probe scores from the fill that probes
them side by side; a margin then picks, per take, the library where its score plus the margin
is at least the network's (as ``pipeline.infer.trust`` picks). The margin chosen is the one of
least mean log pooled ratio to the spline over the four cells (two sources, keys every 10 and
30), declared before the run. Offline study, not a test or a benchmark (docs/models.md).

``python experiments/library_margin.py OUT [--bandai-stride 12] [--margins -0.5,...,0.5]``
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from pipeline.bench.heldout import cmu_files
from pipeline.bench.library import evaluate, fills_for, split
from pipeline.library.build import build
from pipeline.library.store import is_library

METHODS = ("library", "library-spline", "default", "spline")
MARGINS = (-0.5, -0.25, -0.1, 0.0, 0.1, 0.25, 0.5)


def library(out: Path, subjects: tuple[int, ...]) -> Path:
    """The library of these CMU subjects' takes (built once into ``out``)."""
    lib = out / f"library-cmu-{'-'.join(map(str, subjects))}"
    if not is_library(lib):
        build(None, lib, files=cmu_files(subjects), licence="CMU Graphics Lab terms", name=lib.name)
    return lib


def cells(out: Path, stride: int) -> dict:
    """{(source, every): {take: evaluate's row}} over the tuning takes."""
    folds = [(library(out, tuple(x for x in (1, 2, 3) if x != s)), cmu_files((s,))) for s in (1, 2, 3)]
    sets = {"CMU 1-3, each subject held out": folds,
            "Bandai train, takes 3 mod 5": [(library(out, (1, 2, 3)), split("bandai", True)[1][::stride])]}  # fmt: skip
    res: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, pairs in sets.items():
            for every in (10, 30):
                per = res.setdefault(f"{name}, keys every {every}", {})
                for lib, takes in pairs:
                    for i, f in enumerate(takes):
                        print(f"library margin: {name} {i + 1}/{len(takes)} {f.name}, keys every {every}",
                              file=sys.stderr)  # fmt: skip
                        per[f.name] = evaluate(f, every, METHODS, Path(tmp), 300, fills_for(lib))
    return res


def pick(row: dict, margin: float) -> str:
    """The method a fill with this margin gives the take: ``library-spline`` or ``default``."""
    scores = row["methods"]["library"].get("trust", {}).get("scores") or {}
    lib = next((v for k, v in scores.items() if k.startswith("library:")), None)
    net = next((v for k, v in scores.items() if not k.startswith("library:")), None)
    if lib is None and net is not None:  # a score ranks before none (pipeline.infer.trust)
        return "default"
    return "library-spline" if net is None or lib + margin >= net else "default"


def pooled(per: dict, margin: float | None, method: str | None = None) -> float:
    """Pooled mapped-joint error ratio to the spline of the takes' picks (or one method)."""
    num = den = 0.0
    for row in per.values():
        m = method or pick(row, margin)
        num += row["methods"][m]["mapped_sum"]
        den += row["methods"]["spline"]["mapped_sum"]
    return num / max(den, 1e-9)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="folder for the libraries and library_margin.json")
    ap.add_argument("--bandai-stride", type=int, default=12, help="every N-th Bandai tuning take")
    ap.add_argument("--margins", default=",".join(map(str, MARGINS)), help="margins to compare")
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    margins = [float(m) for m in a.margins.split(",")]
    res = cells(a.out, a.bandai_stride)
    table = {c: {"library (measured, margin 0.25)": pooled(per, None, "library"),
                 "network": pooled(per, None, "default"), "library alone": pooled(per, None, "library-spline"),
                 **{f"margin {m:g}": pooled(per, m) for m in margins}} for c, per in res.items()}  # fmt: skip
    cost = {m: float(np.mean([np.log(table[c][f"margin {m:g}"]) for c in table])) for m in margins}
    best = min(margins, key=lambda m: (cost[m], abs(m)))
    (a.out / "library_margin.json").write_text(json.dumps({"per_take": res, "table": table, "cost": cost,
                                                           "chosen": best}, indent=1))  # fmt: skip
    for c, row in table.items():
        print(f"{c}: " + ", ".join(f"{k} {v:.3f}" for k, v in row.items()))
    print("mean log ratio: " + ", ".join(f"{m:g}: {cost[m]:+.4f}" for m in margins) + f"; chosen {best:g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
