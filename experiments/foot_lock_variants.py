"""Choose the foot lock's settings without the eval split.

python experiments/foot_lock_variants.py MODEL_DIR [--every K]

Compares the foot lock's settings (``feet`` and the ``feet_anchor`` / ``feet_orient`` that
model.json gives an ``OnnxInbetweener``, set on it here) on the protocol's task on
windows cut from every 4th train clip (``pipeline.bench.selection.train_windows``): L2P and
foot skate ÷ interpolation, and foot skate per foot joint at 5 frames, where the bar is tightest.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from pipeline.bench.methods import inbetweener_method, interpolation
from pipeline.bench.ratios import cell, ratio_cell
from pipeline.bench.run import evaluate
from pipeline.bench.selection import EVERY, train_windows
from pipeline.data.cache import load_split
from pipeline.data.protocol import CONTEXT, global_positions, position_stats
from pipeline.data.skeletons import FOOT_JOINTS, bandai_skeleton
from pipeline.infer.generator_onnx import OnnxInbetweener

VARIANTS = (
    ("none", None),
    ("anchored (v5.1)", (True, False)),
    ("anchored, orientation held (v5.2)", (True, True)),
)


def skate_per_joint(method, rots, roots, T: int = 5) -> list[float]:
    """Foot skate (cm/frame) on the true contact frames of each foot joint."""
    feet = [bandai_skeleton().index(n) for n in FOOT_JOINTS]
    tgt = CONTEXT + T
    p_rot, p_root = method(rots[:, :CONTEXT], roots[:, :CONTEXT], rots[:, tgt], roots[:, tgt], T)
    _, truth = global_positions(rots[:, CONTEXT - 1 : tgt], roots[:, CONTEXT - 1 : tgt])
    rot = np.concatenate([rots[:, CONTEXT - 1 : CONTEXT], p_rot], 1)
    root = np.concatenate([roots[:, CONTEXT - 1 : CONTEXT], p_root], 1)
    _, pred = global_positions(rot, root)
    contact = np.square(np.diff(truth[:, :, feet], axis=1)).sum(-1) < 0.02
    slide = np.linalg.norm(np.diff(pred[:, :, feet], axis=1)[..., [0, 2]], axis=-1)
    return [float(slide[..., j][contact[..., j]].mean()) for j in range(len(feet))]


def inbetweener(model: str, setting: tuple[bool, bool] | None) -> OnnxInbetweener:
    """The model with one foot-lock setting: None (no lock) or (anchor, orient)."""
    inb = OnnxInbetweener(model)
    if setting is None:
        inb.feet = False
    else:
        inb.feet_anchor, inb.feet_orient = setting
    return inb


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", help="model folder")
    ap.add_argument("--every", type=int, default=EVERY, help="windows from every K-th train clip")
    a = ap.parse_args(argv)
    rots, roots = train_windows(a.every)
    mean, std = position_stats(load_split("train"))
    base = evaluate(interpolation, rots, roots, mean, std)
    print(f"{len(rots)} train windows; ÷ interp at 5 / 15 / 30 / 45; skate per joint at 5 {FOOT_JOINTS}")
    for name, setting in VARIANTS:
        method = inbetweener_method(inbetweener(a.model, setting))
        r = evaluate(method, rots, roots, mean, std)
        l2p, skate = ratio_cell(r, base, "L2P"), ratio_cell(r, base, "skate")
        joints = cell(skate_per_joint(method, rots, roots))
        print(f"| {name} | {l2p} | {skate} | {joints} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
