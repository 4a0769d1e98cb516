"""Model ÷ interpolation rows from `tween bench` JSON files, for the model card.

python scripts/ratio_rows.py LABEL=bench_dir/bench.json ...
Each file must hold an ``interp`` row and one model row.
"""

import json
import sys

for arg in sys.argv[1:]:
    label, path = arg.split("=", 1)
    res = json.load(open(path))["results"]
    model = next(k for k in res if k not in ("interp", "zero"))
    cells = []
    for metric in ("L2P", "L2Q", "NPSS", "skate"):
        ratio = [res[model][t][metric] / res["interp"][t][metric] for t in ("5", "15", "30", "45")]
        cells.append(" / ".join(f"{r:.3f}" for r in ratio))
    print(f"| {label} | " + " | ".join(cells) + " |")
