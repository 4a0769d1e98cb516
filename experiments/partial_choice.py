"""Choose a partial-key model without the eval split.

python experiments/partial_choice.py MODEL_DIR [MODEL_DIR ...] [--every K] [--json OUT]

Each model is measured on protocol windows cut from every K-th train clip (default 8; see
``pipeline.bench.selection.train_windows``): the protocol's task with full keys (L2P and foot
skate ÷ interpolation at 5 / 15 / 30 / 45 frames) and the partial-key task of ``tween bench
--partial-keys`` (one root-only, legs or upper-body key halfway through the transition; L2P
at 15 / 30 / 45). A model without partial-key inputs (key mask or adapter) fills from the full
keys and matches the partial ones afterwards, so its rows are the fallback to beat.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pipeline.bench.methods import inbetweener_method, interpolation
from pipeline.bench.partial import evaluate_partial, fill_interp, json_ready, markdown, model_fill
from pipeline.bench.ratios import cell, ratios
from pipeline.bench.run import evaluate
from pipeline.bench.selection import train_windows
from pipeline.data.cache import load_split
from pipeline.data.protocol import position_stats
from pipeline.infer.generator_onnx import OnnxInbetweener


def compare(models: list[str], every: int, out: str | None) -> dict:
    """Prints the two tables; returns (and with ``out`` writes) the numbers."""
    mean, std = position_stats(load_split("train"))
    rots, roots = train_windows(every)
    print(f"{len(rots)} windows from every {every}th train clip", file=sys.stderr)
    base = evaluate(interpolation, rots, roots, mean, std)
    full, partial = {}, {"interp": evaluate_partial(fill_interp, rots, roots, mean, std)}
    print("| model | L2P ÷ interp, full keys | skate ÷ interp |\n|---|---|---|")
    for path in models:
        inb = OnnxInbetweener(path)
        r = evaluate(inbetweener_method(inb), rots, roots, mean, std)
        l2p, skate = ratios(r, base, "L2P"), ratios(r, base, "skate")
        full[inb.name] = {str(t): {"L2P": l2p[t], "skate": skate[t]} for t in r}
        print(f"| {inb.name} | {cell(l2p.values())} | {cell(skate.values())} |", flush=True)
        partial[inb.name] = evaluate_partial(model_fill(inb), rots, roots, mean, std)
    print()
    print(markdown(partial))
    payload = {"windows": len(rots), "full_keys": full, "partial": json_ready(partial)}
    if out:
        Path(out).write_text(json.dumps(payload, indent=1))
    return payload


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Partial-key models compared on train windows.")
    ap.add_argument("models", nargs="+", help="model folders")
    ap.add_argument("--every", type=int, default=8, help="every K-th train clip")
    ap.add_argument("--json", help="also write the results here")
    a = ap.parse_args(argv)
    compare(a.models, a.every, a.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
