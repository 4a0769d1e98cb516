"""How far the blocking bench's shots are from a model's training poses (docs/trust.md).

For each source of ``python -m pipeline.bench.blocking`` (eval clips, CMU takes on the model
skeleton, eval clips with posture offsets up to 30 degrees), shots keyed every N frames: the
novelty of each shot (median over its keys of the distance to the nearest pose of the
model's pose bank, cm; pipeline.infer.novelty) as quantiles, and the share of shots the
trusted fill counts as familiar, unseen and in between. This is what FAMILIAR_CM and
NOVEL_CM were set from.

``python experiments/key_novelty.py [--model default] [--every 30] [--sources eval,cmu,posture30]``
"""

from __future__ import annotations

import argparse

import numpy as np

from pipeline.bench import blocking
from pipeline.infer import novelty
from pipeline.infer.api import load_inbetweener


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="default", help="a model with a pose bank")
    ap.add_argument("--every", type=int, default=30, help="key spacing, frames")
    ap.add_argument("--sources", default=",".join(blocking.SOURCES))
    a = ap.parse_args(argv)
    net = load_inbetweener(a.model)
    if not net.capabilities.novelty:
        ap.error(f"{a.model}: this model has no pose bank")
    print("| source | shots | p10 | median | p90 | min | max | familiar | between | unseen |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for src in a.sources.split(","):
        rots, roots = blocking.shots(src)
        n = rots.shape[1]
        keys = np.r_[np.arange(0, n - 1, a.every), n - 1]
        d = novelty.novelty_cm(rots[:, keys], roots[:, keys], net.pose_bank, net.skeleton)
        fam = np.array([novelty.familiarity(x) for x in d])
        q = np.percentile(d, [10, 50, 90])
        print(
            f"| {src} | {len(d)} | {q[0]:.2f} | {q[1]:.2f} | {q[2]:.2f} | {d.min():.2f} | {d.max():.2f} "
            f"| {np.mean(fam == 1):.2f} | {np.mean((fam > 0) & (fam < 1)):.2f} | {np.mean(fam == 0):.2f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
