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

``--beside MODEL`` probes a further network beside the library (each rule's table then has a
column with it too); ``--heldout`` adds held-out cells (CMU 5-7, the blocking bench's eval and
posture shots) to the table, which no choice reads.

``python experiments/library_margin.py OUT [--bandai-stride 6] [--margins -0.25,...,0.5]
[--beside models/delta] [--heldout]``
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from pipeline.bench.blocking import SHOT, STRIDE, errors_cm, shots
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


def measure(net, spline, alts, rots, roots, every: int) -> dict:
    """Per shot: the network's, each alternative's (``alt0`` the library, then any network
    probed beside it) and the spline's errors, the scores, and whether the alternatives are
    probed at all."""
    n = rots.shape[1]
    keys = np.r_[np.arange(0, n - 1, every), n - 1]
    free = np.setdiff1d(np.arange(n), keys)
    skel = net.skeleton
    f = trusted_fill_windows(net, spline, rots, roots, keys)
    beside = np.array([probes_beside(net, d) for d in f.decisions])
    out = {"network": errors_cm(skel, *f.decided, rots, roots, free),
           "spline": errors_cm(skel, *f.spline, rots, roots, free),
           "s_net": np.array([d.score if d.score is not None else np.nan for d in f.decisions]),
           "beside": beside}  # fmt: skip
    todo = np.flatnonzero(beside)
    for k, alt in enumerate(alts):
        out[f"alt{k}"], out[f"s_alt{k}"] = np.full(len(rots), np.nan), np.full(len(rots), np.nan)
        if len(todo):
            g = trusted_fill_windows(alt, spline, rots[todo], roots[todo], keys)
            out[f"alt{k}"][todo] = errors_cm(skel, *g.decided, rots[todo], roots[todo], free)
            out[f"s_alt{k}"][todo] = [d.score if d.score is not None else np.nan for d in g.decisions]
    return out


def pooled(m: dict, margin, floor, alts: int = 1) -> float:
    """Pooled error ratio to the spline of the picks margins and a floor (``pick``'s) give,
    among the network and its first ``alts`` alternatives."""
    err = m["network"].copy()
    for i in np.flatnonzero(m["beside"]):
        s = [m["s_net"][i]] + [m[f"s_alt{k}"][i] for k in range(alts)]
        chosen = pick([None if np.isnan(x) else float(x) for x in s], margin, floor)
        if chosen:
            err[i] = m[f"alt{chosen - 1}"][i]
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


def heldout(shipped: Path):
    """(name, [(library folder, rotations, roots)]) of held-out shots, reported beside the
    tuning cells and never used to choose: CMU subjects 5-7 (other actors) and the blocking
    bench's eval shots, as they are and with posture offsets of 10 and 30 degrees."""
    takes = [cmu_on_model_skeleton(f) for f in cmu_files((5, 6, 7))]
    r, p = windows_of(((m.rotations, m.root_positions) for m in takes if len(m) > SHOT), SHOT, STRIDE)
    out = [("held out: CMU 5-7", [(shipped, r, p)])]
    return out + [
        (f"held out: blocking {src}", [(shipped, *shots(src))]) for src in ("eval", "posture10", "posture30")
    ]


# Long because: one offline study, read top to bottom: measure every cell, then every rule.
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="folder for the libraries and library_margin.json")
    ap.add_argument("--bandai-stride", type=int, default=6, help="every N-th Bandai tuning take")
    ap.add_argument("--margins", default=",".join(map(str, MARGINS)), help="the network's margins to compare")
    ap.add_argument(
        "--beside", default=None, help="a further network probed beside the library, e.g. models/delta"
    )
    ap.add_argument(
        "--heldout", action="store_true", help="also measure held-out cells (reported, never chosen on)"
    )
    ap.add_argument("--reuse", action="store_true", help="read the cells a previous run saved in OUT")
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    margins = [float(m) for m in a.margins.split(",")]
    net = load_inbetweener("default")
    more = [load_inbetweener(a.beside)] if a.beside else []
    lib = LibraryInbetweener(str(net.library_folder))
    cells, tune = (
        _reused(a.out) if a.reuse else measure_cells(a.out, net, [lib, *more], a.bandai_stride, a.heldout)
    )
    # The network's margin x swept; the library's and a network beside it as they declare them.
    margins_of, floor = choice_rule(net, [lib, *more])
    rules = {f"margin {x:g}": ([x, *margins_of[1:2]], 1) for x in margins}
    if more:
        rules |= {f"margin {x:g}, + {more[0].name}": ([x, *margins_of[1:]], 2) for x in margins}
    table = {c: {"shots": int(len(m["network"])), "probed": int(m["beside"].sum()),
                 "network": float(m["network"].sum() / m["spline"].sum()),
                 **{r: pooled(m, x, floor, k) for r, (x, k) in rules.items()}} for c, m in cells.items()}  # fmt: skip
    cost = {r: float(np.mean([np.log(table[c][r]) for c in tune])) for r in rules}
    best = min(margins, key=lambda x: (cost[f"margin {x:g}"], -x))
    out = {"table": table, "cost": cost, "chosen": best, "margins": margins_of, "floor": floor,
           "tuning_cells": tune}  # fmt: skip
    if more:  # kept: less cost, and every tuning cell within 0.1 % of the library's alone
        base, with_it = f"margin {best:g}", f"margin {best:g}, + {more[0].name}"
        out["beside_kept"] = cost[with_it] < cost[base] and all(
            table[c][with_it] <= 1.001 * table[c][base] for c in tune
        )
    (a.out / "library_margin.json").write_text(json.dumps(out, indent=1))
    for c, row in table.items():
        print(f"{c}: " + ", ".join(f"{k} {v:.4g}" for k, v in row.items()))
    print("mean log ratio over the tuning cells: " + ", ".join(f"{r}: {v:+.4f}" for r, v in cost.items()))
    print(f"chosen margin {best:g}" + (f"; {more[0].name} kept beside: {out['beside_kept']}" if more else ""))
    return 0


def measure_cells(out: Path, net, alts, stride: int, held: bool) -> tuple[dict, list]:
    """Every cell's per-shot measures (saved in ``out``, one .npz a cell), and the tuning cells' names."""
    spline = SplineInbetweener(net.skeleton)
    parts_of = sources(out, stride, net.library_folder)
    tuning = len(parts_of)
    if held:
        parts_of += heldout(net.library_folder)
    cells: dict = {}
    for name, parts in parts_of:
        for every in (10, 30):
            print(f"library margin: {name}, keys every {every}…", file=sys.stderr)
            got = [measure(net, spline, [LibraryInbetweener(str(lib)), *alts[1:]], r.astype(np.float32),
                           p.astype(np.float32), every) for lib, r, p in parts]  # fmt: skip
            cells[f"{name}, keys every {every}"] = {k: np.concatenate([g[k] for g in got]) for k in got[0]}
    for c, m in cells.items():  # per shot, for what a later rule may be checked on (--reuse)
        np.savez(out / _npz_name(c), **m)
    tune = list(cells)[: 2 * tuning]
    (out / "cells.json").write_text(json.dumps({"cells": list(cells), "tuning": tune}))
    return cells, tune


def _npz_name(cell: str) -> str:
    return cell.replace(" ", "_").replace(",", "").replace(":", "") + ".npz"


def _reused(out: Path) -> tuple[dict, list]:
    names = json.loads((out / "cells.json").read_text())
    return {c: dict(np.load(out / _npz_name(c))) for c in names["cells"]}, names["tuning"]


if __name__ == "__main__":
    raise SystemExit(main())
