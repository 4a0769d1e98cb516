"""How far a foot the keys plant is held in the trusted fill's curve: PLANT_HEIGHT_CM and PLANT_TRAVEL_CM.

pipeline.infer.plant holds a foot through a gap where both keys have its ankle near the ground
(at most the height above the lowest it is at any key) and in nearly the same place (at most the
travel along the ground). Per setting, the curve's world joint error between the keys (cm, FK
on the model skeleton) with the feet planted ÷ the curve's without, pooled, and the worst take.

Tuning takes only (no bench's held-out takes): CMU subjects 1-3 on the model skeleton (the
product's retarget path, 30 fps) and every third Bandai dataset-2 train take numbered 3 mod 5
(the library bench's tuning split), first 300 frames each, keyed every 10 and 30 frames. And,
at the shipped setting, the motions that end in holds of experiments/curve_tangents.py.

``python experiments/foot_plant.py [--subjects 1,2,3] [--bandai-stride 3] [--out FILE.json]``
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from dataclasses import replace

import numpy as np

from pipeline.bench.heldout import cmu_files
from pipeline.data.split import list_clips, shared_data_dir
from pipeline.infer import plant
from pipeline.infer.spline import spline_motion
from pipeline.infer.trust import CURVE
from pipeline.motion.bvh import read_bvh
from pipeline.motion.fk import fk
from pipeline.usd.take import model_take

#: (height cm, travel cm) settings; None: the curve as it is.
SETTINGS = (None, (6.0, 3.0), (10.0, 6.0), (15.0, 6.0), (10.0, 10.0), (20.0, 10.0))


def takes(subjects: tuple[int, ...], bandai_stride: int) -> dict[str, list]:
    cmu = [(f.name, model_take(f, 30.0)) for f in cmu_files(subjects)]
    files = [
        f
        for f in list_clips("train")
        if f.name.startswith("dataset-2_") and int(re.search(r"_(\d+)\.bvh", f.name)[1]) % 5 == 3
    ]
    return {"cmu": cmu, "bandai": [(f.name, read_bvh(f)) for f in files[::bandai_stride]]}


def holds() -> dict:
    """At the shipped setting, on the motions that end in holds experiments/curve_tangents.py
    measures (the first 12 raise-up and 8 wave takes of Bandai dataset-2, train and eval alike):
    world joint error between the keys (cm) of the DCC spline (PCHIP), the curve, and the curve
    with the feet held, keys every 10 and 15 frames."""
    folder = shared_data_dir() / "bandai_namco" / "dataset-2"
    files = sorted(folder.glob("dataset-2_raise-up-*"))[:12] + sorted(folder.glob("dataset-2_wave-*"))[:8]
    out = {}
    for every in (10, 15):
        sums = {"pchip": 0.0, "curve": 0.0, "planted": 0.0}
        frames = 0
        for f in files:
            m = read_bvh(f)
            n = min(len(m.rotations), 300)
            m = replace(m, rotations=m.rotations[:n], root_positions=m.root_positions[:n])
            keys = np.unique(np.r_[np.arange(0, n, every), n - 1])
            between = np.setdiff1d(np.arange(n), keys)
            true = positions(m, m.rotations)
            curve = spline_motion(m, keys, CURVE)
            pchip = spline_motion(m, keys, "pchip")
            held = plant.plant_feet(curve, keys, plant.model_feet(m.skeleton))
            for name, fill in (("pchip", pchip), ("curve", curve), ("planted", held)):
                pos = positions(fill, fill.rotations)
                sums[name] += float(np.linalg.norm(pos[between] - true[between], axis=-1).sum())
            frames += len(between) * len(m.skeleton.names)
        out[f"every {every}"] = {k: v / frames for k, v in sums.items()} | {
            "curve_over_pchip": sums["curve"] / sums["pchip"],
            "planted_over_pchip": sums["planted"] / sums["pchip"],
        }
    return {"takes": len(files), "cm": out}


def positions(m, rot) -> np.ndarray:
    return fk(
        rot.astype(np.float64), m.root_positions.astype(np.float64), m.skeleton.parents, m.skeleton.offsets
    )[1]


def measure(clips: list, every: int) -> dict:
    sums = {str(s): 0.0 for s in SETTINGS}
    worst = {str(s): ("", 0.0) for s in SETTINGS}
    frames = 0
    for name, m in clips:
        n = min(len(m.rotations), 300)
        if n < every + 2:
            continue
        m = replace(m, rotations=m.rotations[:n], root_positions=m.root_positions[:n])
        keys = np.unique(np.r_[np.arange(0, n, every), n - 1])
        curve = spline_motion(m, keys, CURVE)
        feet = plant.model_feet(m.skeleton)
        true = positions(m, m.rotations)
        between = np.setdiff1d(np.arange(n), keys)
        base = None
        for s in SETTINGS:
            rot = curve.rotations
            if s is not None:
                plant.PLANT_HEIGHT_CM, plant.PLANT_TRAVEL_CM = s
                rot = plant.plant_feet(curve, keys, feet).rotations
            err = (
                float(np.linalg.norm(positions(curve, rot)[between] - true[between], axis=-1).mean())
                * 100
                * m.skeleton.meters_per_unit
            )
            base = err if s is None else base
            sums[str(s)] += err * len(between)
            if err / base > worst[str(s)][1]:
                worst[str(s)] = (name, round(err / base, 4))
        frames += len(between)
    ref = sums["None"]
    return {k: {"cm": v / frames, "ratio": v / ref, "worst_take": worst[k]} for k, v in sums.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--subjects", default="1,2,3", help="CMU subjects of the tuning takes")
    ap.add_argument("--bandai-stride", type=int, default=3, help="every Nth Bandai tuning take")
    ap.add_argument("--out", help="write the results as JSON here")
    a = ap.parse_args(argv)
    saved = plant.PLANT_HEIGHT_CM, plant.PLANT_TRAVEL_CM
    sources = takes(tuple(int(s) for s in a.subjects.split(",")), a.bandai_stride)
    out = {}
    try:
        for source, clips in sources.items():
            for every in (10, 30):
                print(f"{source}: keys every {every}…", file=sys.stderr)
                out[f"{source} every {every}"] = measure(clips, every)
    finally:
        plant.PLANT_HEIGHT_CM, plant.PLANT_TRAVEL_CM = saved
    print("motions that end in holds…", file=sys.stderr)
    ends_in_holds = holds()
    for cell, rows in out.items():
        for s, r in rows.items():
            print(
                f"{cell}\t{s}\t{r['cm']:.3f} cm\t{r['ratio']:.4f}\tworst {r['worst_take'][0]} {r['worst_take'][1]}"
            )
    for cell, r in ends_in_holds["cm"].items():
        print(
            f"holds {cell}\tcurve ÷ PCHIP {r['curve_over_pchip']:.4f}\tplanted ÷ PCHIP {r['planted_over_pchip']:.4f}"
        )
    if a.out:
        with open(a.out, "w") as f:
            json.dump(
                {"takes": {k: len(v) for k, v in sources.items()}, "results": out, "holds": ends_in_holds},
                f,
                indent=1,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
