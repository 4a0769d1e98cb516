"""A small library shipped beside the network: the CMU takes of some subjects as a library,
probed beside the shipped network with a given probe margin (``LibraryInbetweener.capabilities.probe_margin``;
a studio's own library gets 0.25), measured through the product path on other actors (CMU
subjects 5-7) and on Bandai eval-split takes (every ``--bandai-stride``-th), keys every 10 and 30.
Offline study, not a test or a benchmark (docs/models.md, "Longer offset fine-tunes and delta
inputs").

``python experiments/shipped_library.py OUT [--subjects 1,2,3] [--margin 0.25] [--bandai-stride 15] [--methods library,default,spline]``
"""

from __future__ import annotations

import argparse
import json
import tempfile
from dataclasses import replace
from pathlib import Path

from pipeline.bench.heldout import cmu_files
from pipeline.bench.library import markdown, subjects_library, summary
from pipeline.bench.studio import evaluate_take
from pipeline.data.split import list_clips
from pipeline.library.infer import LibraryInbetweener

METHODS = ("library", "default", "spline")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="folder for the library and shipped_library.json/.md")
    ap.add_argument("--subjects", default="1,2,3", help="CMU subjects in the library")
    ap.add_argument("--margin", type=float, default=0.25, help="the library's probe margin")
    ap.add_argument("--bandai-stride", type=int, default=15, help="every N-th Bandai eval take")
    ap.add_argument("--methods", default=",".join(METHODS),
                    help="columns: library, default, spline, or a human model's name (its trusted fill)")  # fmt: skip
    a = ap.parse_args(argv)
    methods = tuple(m for m in a.methods.split(",") if m)
    if "spline" not in methods:
        methods += ("spline",)  # every ratio is to it
    subjects = tuple(int(s) for s in a.subjects.split(","))
    lib = subjects_library(a.out, subjects)
    LibraryInbetweener.capabilities = replace(LibraryInbetweener.capabilities, probe_margin=a.margin)
    fills = {"library": {"library": str(lib), "trust": "auto"}, "default": {"model": "default", "trust": "auto"},
             "spline": {"model": "spline", "trust": "auto"}}  # fmt: skip
    fills |= {m: {"model": m, "trust": "auto"} for m in methods if m not in fills}
    rep = {"every": [10, 30], "methods": list(methods), "max_frames": 300, "sources": {}}
    held_sets = (("CMU 5-7", cmu_files((5, 6, 7))), ("Bandai eval", list_clips("eval")[:: a.bandai_stride]))
    for name, held in held_sets:
        per: dict = {10: {}, 30: {}}
        with tempfile.TemporaryDirectory() as tmp:
            for f in held:
                for e in per:
                    per[e][f.name] = evaluate_take(f, e, methods, Path(tmp), 300, True, 30.0, fills=fills)
        rep["sources"][f"{name}, margin {a.margin:g}"] = {
            "held_out": [f.name for f in held],
            "per_take": per,
            "summary": summary(per, methods),
        }
    (a.out / "shipped_library.json").write_text(json.dumps(rep, indent=1))
    (a.out / "shipped_library.md").write_text(markdown(rep))
    print(markdown(rep))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
