"""The model skeleton's typical pose: each joint's mean local rotation over the train split.

A rig that lacks a model joint (no clavicles, one spine joint fewer, no hands) still maps
(pipeline/adapt/mapping.py); the retarget gives the joint it lacks this rotation
(pipeline/adapt/retarget.py, ``typical_local``), the pose the network saw most, and keeps its
children's world rotations. The mean is scipy's quaternion mean (chordal L2) over every
frame of every train clip; eval clips are not read. Writes pipeline/adapt/bandai_mean.json.

``python scripts/mean_pose.py [--out pipeline/adapt/bandai_mean.json]``
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.data.cache import load_split
from pipeline.data.skeletons import bandai_skeleton

OUT = Path(__file__).resolve().parents[1] / "pipeline" / "adapt" / "bandai_mean.json"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args(argv)
    skel = bandai_skeleton()
    clips = load_split("train")
    rots = np.concatenate([clips.clip(c)[0] for c in range(len(clips))]).astype(np.float64)
    mean = {
        name: [round(float(v), 7) for v in Rotation.from_quat(rots[:, j]).mean().as_quat(canonical=True)]
        for j, name in enumerate(skel.names)
    }
    doc = {
        "source": (
            "Bandai Namco Research Motion Dataset 1 and 2 (CC BY-NC 4.0), train split: "
            f"each joint's mean local rotation over {len(rots):,} frames of {len(clips):,} clips "
            "(scripts/mean_pose.py)."
        ),
        "rotations_xyzw": mean,
    }
    a.out.write_text(json.dumps(doc, indent=1) + "\n")
    print(a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
