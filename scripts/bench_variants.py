"""Extra benchmark rows for the model card: post-processing and root-source switches.

python scripts/bench_variants.py MODEL_DIR [SUPERVISED_MODEL_DIR] > rows.md
Each row is the full protocol (PROTOCOL.md) with one inference switch changed.
"""

import json
import sys

from pipeline.bench.methods import inbetweener_method, interpolation
from pipeline.bench.protocol import TRANSITIONS, position_stats
from pipeline.bench.run import evaluate, markdown, test_windows
from pipeline.data.cache import load_split
from pipeline.infer.model import OnnxInbetweener

model = sys.argv[1]
mean, std = position_stats(load_split("train"))
rots, roots = test_windows(None)
variants = {
    "interp": interpolation,
    "model (shipped: generator root, foot IK)": inbetweener_method(OnnxInbetweener(model)),
    "model without foot IK": inbetweener_method(OnnxInbetweener(model, feet=False)),
    "model, root from path predictor": inbetweener_method(OnnxInbetweener(model, root="path")),
    "model, mirror-averaged": inbetweener_method(OnnxInbetweener(model, mirror=True)),
}
if len(sys.argv) > 2:
    variants["model before LSGAN refinement"] = inbetweener_method(OnnxInbetweener(sys.argv[2]))
results = {}
for name, method in variants.items():
    print(f"evaluating {name}…", file=sys.stderr)
    results[name] = evaluate(method, rots, roots, mean, std)
print(markdown(results, len(rots), TRANSITIONS))
json.dump(
    {k: {str(t): v for t, v in r.items()} for k, r in results.items()},
    open("runs/bench_variants.json", "w"),
    indent=1,
)
