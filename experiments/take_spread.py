"""How far apart the takes of one model are: python experiments/take_spread.py MODEL_DIR [MODEL_DIR ...]

Fills an eval walk (keys every 30 frames) with seeds 0, 3 and 4 and prints the mean and largest
joint distance (cm) between each pair of takes.
"""

from __future__ import annotations

import argparse
import itertools
import sys

import numpy as np

from pipeline.data.split import shared_data_dir
from pipeline.infer.generator_onnx import OnnxInbetweener
from pipeline.motion.bvh import read_bvh

CLIP = "bandai_namco/dataset-2/dataset-2_walk_active_002.bvh.gz"


def take_distances(inb, motion, keys, seeds=(0, 3, 4)) -> list[np.ndarray]:
    """(T, J) joint distances between the fills of each pair of ``seeds``."""
    outs = {s: inb.fill(motion, keys, seed=s).positions() for s in seeds}
    return [np.linalg.norm(outs[a] - outs[b], axis=-1) for a, b in itertools.combinations(outs, 2)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0].split(":")[0])
    ap.add_argument("models", nargs="+", help="model folders")
    ap.add_argument("--every", type=int, default=30, help="key spacing in frames")
    ap.add_argument("--seeds", default="0,3,4", help="comma-separated take seeds")
    a = ap.parse_args(argv)
    seeds = tuple(int(s) for s in a.seeds.split(","))
    m = read_bvh(shared_data_dir() / CLIP).continuous()
    keys = np.unique(np.r_[np.arange(0, len(m), a.every), len(m) - 1])
    for folder in a.models:
        d = take_distances(OnnxInbetweener(folder), m, keys, seeds)
        print(
            folder,
            len(m),
            "frames",
            "mean",
            [round(float(x.mean()), 3) for x in d],
            "max",
            round(float(max(x.max() for x in d)), 3),
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
