"""The probe margin by which the default network must be beaten by the library shipped beside
it, chosen on a tuning split that holds neither the benches' other actors (CMU 5-7) nor
Bandai's eval split.

Tuning shots (181 frames, as the blocking bench cuts them, on the model skeleton): each of CMU
subjects 1, 2 and 3 held out in turn from a library of the other two (other actors, as the
shipped library meets them); and the Bandai dataset-2 train takes numbered 3 mod 5 (every
``--bandai-stride``-th) as they are and with posture offsets up to 30 degrees (the network's
kind of motion on a posture it never saw), against the shipped library (CMU 1-3). Per shot and
key spacing (10, 30): the network's trusted fill, the library's trusted fill, the spline, and
both probe scores; a margin then gives a shot the library where the network's keys are not as
familiar as its training data (``pipeline.infer.trust.probes_beside``) and the library's score
beats the network's plus the margin and the spline (``pick``, ``choice_rule``). Chosen: the margin of least mean log pooled
ratio to the spline over the six cells, declared before the run. Offline study, not a test or a
benchmark (docs/models.md, The library shipped beside the network).

``python experiments/library_margin.py OUT [--bandai-stride 6] [--margins -0.25,...,0.5]``
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from pipeline.bench.blocking import SHOT, STRIDE, errors_cm
from pipeline.bench.heldout import cmu_files
from pipeline.bench.library import split, subjects_library
from pipeline.bench.long_gaps import cmu_on_model_skeleton
from pipeline.data.cache import load_files
from pipeline.data.protocol import windows_of
from pipeline.infer.api import load_inbetweener
from pipeline.infer.spline import SplineInbetweener
from pipeline.infer.trust import choice_rule, pick, probes_beside, trusted_fill_windows
from pipeline.library.infer import LibraryInbetweener
from pipeline.motion.augment import posture_offsets

MARGINS = (-0.25, -0.1, 0.0, 0.1, 0.25, 0.5)


def measure(net, spline, lib, rots, roots, every: int) -> dict:
    """Per shot: the network's, the library's and the spline's errors, both scores, and
    whether the library is probed at all."""
    n = rots.shape[1]
    keys = np.r_[np.arange(0, n - 1, every), n - 1]
    free = np.setdiff1d(np.arange(n), keys)
    skel = net.skeleton
    f = trusted_fill_windows(net, spline, rots, roots, keys)
    beside = np.array([probes_beside(net, d) for d in f.decisions])
    out = {"network": errors_cm(skel, *f.decided, rots, roots, free),
           "spline": errors_cm(skel, *f.spline, rots, roots, free),
           "s_net": np.array([d.score if d.score is not None else np.nan for d in f.decisions]),
           "beside": beside, "library": np.full(len(rots), np.nan), "s_lib": np.full(len(rots), np.nan)}  # fmt: skip
    todo = np.flatnonzero(beside)
    if len(todo):
        g = trusted_fill_windows(lib, spline, rots[todo], roots[todo], keys)
        out["library"][todo] = errors_cm(skel, *g.decided, rots[todo], roots[todo], free)
        out["s_lib"][todo] = [d.score if d.score is not None else np.nan for d in g.decisions]
    return out


def pooled(m: dict, margin: float, floor: float | None) -> float:
    """Pooled error ratio to the spline of the picks a margin (and the network's floor) gives."""
    err = m["network"].copy()
    for i in np.flatnonzero(m["beside"]):
        scores = [None if np.isnan(s) else float(s) for s in (m["s_net"][i], m["s_lib"][i])]
        if pick(scores, margin, floor) == 1:
            err[i] = m["library"][i]
    return float(err.sum() / m["spline"].sum())


def sources(out: Path, stride: int, shipped: Path):
    """(name, [(library folder, rotations, roots)]) of the tuning shots."""
    cmu = []
    for s in (1, 2, 3):
        takes = [cmu_on_model_skeleton(f) for f in cmu_files((s,))]
        takes = [m for m in takes if len(m) > SHOT]  # subject 3's two takes are shorter than a shot
        if takes:
            r, p = windows_of(((m.rotations, m.root_positions) for m in takes), SHOT, STRIDE)
            cmu.append((subjects_library(out, tuple(x for x in (1, 2, 3) if x != s)), r, p))
    clips = load_files(split("bandai", True)[1][::stride], "bandai-tuning")
    r, p = windows_of((clips.clip(c) for c in range(len(clips))), SHOT, STRIDE)
    posed = posture_offsets(r, np.random.default_rng(0), 30.0, 1.0)
    return [("CMU 1-3, each subject held out", cmu), ("Bandai train 3 mod 5", [(shipped, r, p)]),
            ("Bandai train 3 mod 5, posture 30", [(shipped, posed, p)])]  # fmt: skip


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="folder for the libraries and library_margin.json")
    ap.add_argument("--bandai-stride", type=int, default=6, help="every N-th Bandai tuning take")
    ap.add_argument("--margins", default=",".join(map(str, MARGINS)), help="the network's margins to compare")
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    margins = [float(m) for m in a.margins.split(",")]
    net = load_inbetweener("default")
    spline = SplineInbetweener(net.skeleton)
    floor = choice_rule(net)[1]
    cells: dict = {}
    for name, parts in sources(a.out, a.bandai_stride, net.library_folder):
        for every in (10, 30):
            print(f"library margin: {name}, keys every {every}…", file=sys.stderr)
            got = [measure(net, spline, LibraryInbetweener(str(lib)), r.astype(np.float32), p.astype(np.float32),
                           every) for lib, r, p in parts]  # fmt: skip
            cells[f"{name}, keys every {every}"] = {k: np.concatenate([g[k] for g in got]) for k in got[0]}
    table = {c: {"shots": int(len(m["network"])), "probed": int(m["beside"].sum()),
                 "network": float(m["network"].sum() / m["spline"].sum()),
                 **{f"margin {x:g}": pooled(m, x, floor) for x in margins}} for c, m in cells.items()}  # fmt: skip
    cost = {x: float(np.mean([np.log(table[c][f"margin {x:g}"]) for c in table])) for x in margins}
    best = min(margins, key=lambda x: (cost[x], -x))
    for c, m in cells.items():  # per shot, for what a later rule may be checked on
        np.savez(a.out / f"{c.replace(' ', '_').replace(',', '')}.npz", **m)
    (a.out / "library_margin.json").write_text(
        json.dumps({"table": table, "cost": cost, "chosen": best, "floor": floor}, indent=1)
    )
    for c, row in table.items():
        print(f"{c}: " + ", ".join(f"{k} {v:.4g}" for k, v in row.items()))
    print("mean log ratio: " + ", ".join(f"{x:g}: {cost[x]:+.4f}" for x in margins) + f"; chosen {best:g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
