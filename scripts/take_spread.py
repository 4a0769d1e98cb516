"""How far apart the takes of one model are: python scripts/take_spread.py MODEL_DIR [MODEL_DIR ...]

Fills an eval walk (keys every 30 frames) with seeds 0, 3 and 4 and prints the mean and largest
joint distance (cm) between each pair of takes.
"""

import itertools
import sys

import numpy as np

from pipeline.data.split import shared_data_dir
from pipeline.infer.model import OnnxInbetweener
from pipeline.motion.bvh import read_bvh

m = read_bvh(shared_data_dir() / "bandai_namco/dataset-2/dataset-2_walk_active_002.bvh.gz").continuous()
keys = np.r_[np.arange(0, len(m), 30), len(m) - 1]
keys = np.unique(keys)
for folder in sys.argv[1:]:
    inb = OnnxInbetweener(folder)
    outs = {s: inb.fill(m, keys, seed=s).positions() for s in (0, 3, 4)}
    d = [np.linalg.norm(outs[a] - outs[b], axis=-1) for a, b in itertools.combinations(outs, 2)]
    print(
        folder,
        len(m),
        "frames",
        "mean",
        [round(float(x.mean()), 3) for x in d],
        "max",
        round(float(max(x.max() for x in d)), 3),
    )
