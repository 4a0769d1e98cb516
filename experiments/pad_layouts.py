"""Choose the generator's padded window length without the eval split.

python experiments/pad_layouts.py MODEL_DIR [--cmu] [--eval] [--every K]

The network takes windows a multiple of 32 frames long, so a shot is padded, holding the last
key (the ``hold-key`` layout, the only one the fill has kept; the other layouts were compared
on v4, models/default/HISTORY.md, Pad layout). The padded window's length (``pad_tail`` frames
at least after the last key, ``min_window`` frames at least: model.json's, set on the
``OnnxInbetweener`` here) is compared on the protocol's task (10 context frames, a target
after 5/15/30/45 frames) on windows cut as PROTOCOL.md cuts them from every 4th train clip
(``pipeline.bench.selection.train_windows``) and from the CMU takes mapped onto the model
skeleton (``pipeline.bench.heldout``). ``--eval`` adds the same rows on the eval split, for the
record only: the choice is made on the train windows (the CMU rows show whether it carries
over to another source).
"""

from __future__ import annotations

import argparse
import sys

from pipeline.bench.heldout import cmu_windows
from pipeline.bench.methods import inbetweener_method, interpolation
from pipeline.bench.ratios import cell, ratio_cell
from pipeline.bench.run import evaluate, test_windows
from pipeline.bench.selection import EVERY, train_windows
from pipeline.data.cache import load_split
from pipeline.data.protocol import position_stats
from pipeline.infer.generator_onnx import OnnxInbetweener

# (pad_tail, min_window): the next multiple of 32 first, then longer windows.
WINDOWS = ((0, 0), (0, 64), (0, 96), (16, 64), (24, 64))


def inbetweener(model: str, tail: int, least: int) -> OnnxInbetweener:
    """The model padding to at least ``least`` frames, ``tail`` of them after the last key."""
    inb = OnnxInbetweener(model)
    inb.pad_tail, inb.min_window = tail, least
    return inb


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", help="model folder")
    ap.add_argument("--cmu", action="store_true", help="also the CMU takes mapped onto the model skeleton")
    ap.add_argument("--eval", action="store_true", help="also the eval split (for the record only)")
    ap.add_argument("--every", type=int, default=EVERY, help="windows from every K-th train clip")
    a = ap.parse_args(argv)
    mean, std = position_stats(load_split("train"))
    sets = {f"train (every {a.every}th clip)": train_windows(a.every)}
    if a.cmu:
        sets["cmu"] = cmu_windows()
    if a.eval:
        sets["eval"] = test_windows(None)
    for name, (rots, roots) in sets.items():
        base = evaluate(interpolation, rots, roots, mean, std)
        print(f"\n{name}: {len(rots)} windows; L2P ÷ interp at 5 / 15 / 30 / 45 (skate cm/frame)")
        for tail, least in WINDOWS:
            r = evaluate(inbetweener_method(inbetweener(a.model, tail, least)), rots, roots, mean, std)
            ratio, skate = ratio_cell(r, base, "L2P"), cell(r[t]["skate"] for t in r)
            print(f"| hold-key, tail {tail}, window ≥ {least} | {ratio} | {skate} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
