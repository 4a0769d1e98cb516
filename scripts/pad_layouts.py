"""Choose the generator's pad layout without the eval split.

python scripts/pad_layouts.py MODEL_DIR [--eval]

The network takes windows a multiple of 32 frames long, so a shot is padded. The layouts of
``OnnxInbetweener(pad=...)`` are compared on the protocol's task (10 context frames, a
target after 5/15/30/45 frames) on windows cut as PROTOCOL.md cuts them from every 4th
train clip and from the CMU takes mapped onto the model skeleton (``pipeline.bench.heldout``).
``--eval`` adds the same rows on the eval split, for the record only: the choice is made on
the train windows (the CMU rows show whether it carries over to another source).
"""

import sys

from pipeline.bench.heldout import cmu_windows
from pipeline.bench.methods import inbetweener_method, interpolation
from pipeline.bench.protocol import TEST_STRIDE, TEST_WINDOW, normalize_windows, position_stats, windows_of
from pipeline.bench.run import evaluate, test_windows
from pipeline.data.cache import load_split
from pipeline.infer.model import OnnxInbetweener

LAYOUTS = ("end", "hold-key", "front")


def train_windows(every: int = 4):
    """Protocol windows cut from every ``every``-th train clip (seen in training: the layouts are
    a question of input format, not of what the model memorised)."""
    clips = load_split("train")
    picked = (clips.clip(c) for c in range(0, len(clips), every))
    return normalize_windows(*windows_of(picked, TEST_WINDOW, TEST_STRIDE))


def main(model: str, with_eval: bool) -> None:
    mean, std = position_stats(load_split("train"))
    sets = {"train (every 4th clip)": train_windows(), "cmu": cmu_windows()}
    if with_eval:
        sets["eval"] = test_windows(None)
    for name, (rots, roots) in sets.items():
        base = evaluate(interpolation, rots, roots, mean, std)
        print(f"\n{name}: {len(rots)} windows; L2P ÷ interp at 5 / 15 / 30 / 45 (skate cm/frame)")
        for layout in LAYOUTS:
            r = evaluate(inbetweener_method(OnnxInbetweener(model, pad=layout)), rots, roots, mean, std)
            ratio = " / ".join(f"{r[t]['L2P'] / base[t]['L2P']:.3f}" for t in r)
            skate = " / ".join(f"{r[t]['skate']:.3f}" for t in r)
            print(f"| {layout} | {ratio} | {skate} |", flush=True)


if __name__ == "__main__":
    main(sys.argv[1], "--eval" in sys.argv)
