"""Model ÷ interpolation rows from `tween bench` JSON files, for the model card.

python scripts/ratio_rows.py LABEL=bench_dir/bench.json ...

Each file must hold an ``interp`` row and one model row; each argument prints one Markdown row
(L2P, L2Q, NPSS and foot skate ratios at 5 / 15 / 30 / 45 frames;
``pipeline.bench.ratios.bench_ratio_row``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pipeline.bench.ratios import bench_ratio_row


def labelled(arg: str) -> tuple[str, Path]:
    label, sep, path = arg.partition("=")
    if not sep or not label or not path:
        raise argparse.ArgumentTypeError(f"{arg!r}: expected LABEL=PATH")
    return label, Path(path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "rows", nargs="+", type=labelled, metavar="LABEL=BENCH_JSON", help="a row's label and file"
    )
    a = ap.parse_args(argv)
    for label, path in a.rows:
        print(bench_ratio_row(label, json.loads(path.read_text())["results"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
