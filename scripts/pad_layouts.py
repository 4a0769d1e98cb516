"""Choose the generator's pad layout without the eval split.

python scripts/pad_layouts.py MODEL_DIR [--cmu] [--eval]

The network takes windows a multiple of 32 frames long, so a shot is padded. The layouts of
``OnnxInbetweener(pad=...)``, and the padded window's length (``pad_tail`` frames at least
after the last key, ``min_window`` frames at least), are compared on the protocol's task (10 context frames, a
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

# (layout, pad_tail, min_window): the next multiple of 32 first, then longer windows.
LAYOUTS = (
    ("end", 0, 0),
    ("hold-key", 0, 0),
    ("front", 0, 0),
    ("front", 0, 64),
    ("hold-key", 0, 64),
    ("hold-key", 0, 96),
    ("hold-key", 16, 64),
    ("hold-key", 24, 64),
)


def train_windows(every: int = 4):
    """Protocol windows cut from every ``every``-th train clip (seen in training: the layouts are
    a question of input format, not of what the model memorised)."""
    clips = load_split("train")
    picked = (clips.clip(c) for c in range(0, len(clips), every))
    return normalize_windows(*windows_of(picked, TEST_WINDOW, TEST_STRIDE))


def main(model: str, with_eval: bool) -> None:
    mean, std = position_stats(load_split("train"))
    sets = {"train (every 4th clip)": train_windows()}
    if "--cmu" in sys.argv:
        sets["cmu"] = cmu_windows()
    if with_eval:
        sets["eval"] = test_windows(None)
    for name, (rots, roots) in sets.items():
        base = evaluate(interpolation, rots, roots, mean, std)
        print(f"\n{name}: {len(rots)} windows; L2P ÷ interp at 5 / 15 / 30 / 45 (skate cm/frame)")
        for layout, tail, least in LAYOUTS:
            inb = OnnxInbetweener(model, pad=layout, pad_tail=tail, min_window=least)
            r = evaluate(inbetweener_method(inb), rots, roots, mean, std)
            ratio = " / ".join(f"{r[t]['L2P'] / base[t]['L2P']:.3f}" for t in r)
            skate = " / ".join(f"{r[t]['skate']:.3f}" for t in r)
            print(f"| {layout}, tail {tail}, window ≥ {least} | {ratio} | {skate} |", flush=True)


if __name__ == "__main__":
    main(sys.argv[1], "--eval" in sys.argv)
