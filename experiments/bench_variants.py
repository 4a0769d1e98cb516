"""Extra benchmark rows for the model card: post-processing and root-source switches.

python experiments/bench_variants.py MODEL_DIR [SUPERVISED_MODEL_DIR] [--out runs/bench_variants.json] > rows.md

Each row is the full protocol (PROTOCOL.md) with one inference switch changed.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pipeline.bench.methods import inbetweener_method, interpolation
from pipeline.bench.run import evaluate, markdown, test_windows
from pipeline.data.cache import load_split
from pipeline.data.protocol import TRANSITIONS, position_stats
from pipeline.infer.generator_onnx import OnnxInbetweener


def variants(model: str, supervised: str | None = None) -> dict:
    """The methods compared: interpolation, the shipped settings and one switch each."""
    out = {
        "interp": interpolation,
        "model (shipped: generator root, foot IK)": inbetweener_method(OnnxInbetweener(model)),
        "model without foot IK": inbetweener_method(OnnxInbetweener(model, feet=False)),
        "model, root from path predictor": inbetweener_method(OnnxInbetweener(model, root="path")),
        "model, mirror-averaged": inbetweener_method(OnnxInbetweener(model, mirror=True)),
    }
    if supervised:
        out["model before LSGAN refinement"] = inbetweener_method(OnnxInbetweener(supervised))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", help="model folder")
    ap.add_argument("supervised", nargs="?", default=None, help="the same model before LSGAN refinement")
    ap.add_argument("--out", type=Path, default=Path("runs") / "bench_variants.json", help="JSON results")
    a = ap.parse_args(argv)
    mean, std = position_stats(load_split("train"))
    rots, roots = test_windows(None)
    results = {}
    for name, method in variants(a.model, a.supervised).items():
        print(f"evaluating {name}…", file=sys.stderr)
        results[name] = evaluate(method, rots, roots, mean, std)
    print(markdown(results, len(rots), TRANSITIONS))
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({k: {str(t): v for t, v in r.items()} for k, r in results.items()}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
