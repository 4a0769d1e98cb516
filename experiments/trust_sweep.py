"""Per-shot evidence and outcome of the trusted fill on blocked shots (docs/benchmarks.md, Blocked
shots): for each source of the blocking bench (and ``mirrored``) and key
spacing, every shot's probe errors, key novelty, the decided fill's error and the error of
a model/spline blend at nine fixed weights, saved as ``OUT/d_<source>_<every>.npz``; then,
per source and spacing, the task's mean log ratio (spline / model error between the keys) in
bins of the probes' mean log ratio. Offline study, not a test or a benchmark.

``python experiments/trust_sweep.py OUT [--sources eval,cmu,...] [--every 8,10,15,20,30,40]``
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from pipeline.bench import blocking
from pipeline.data.skeletons import bandai_mirror, bandai_skeleton
from pipeline.infer import trust
from pipeline.infer.api import load_inbetweener
from pipeline.infer.spline import SplineInbetweener

GRID = np.linspace(0.0, 1.0, 9)
BINS = [-9.0, -0.6, -0.3, -0.15, 0.0, 0.15, 0.3, 9.0]


def shots(name: str):
    if name != "mirrored":
        return blocking.shots(name)
    r, p = blocking.shots("eval")
    m = bandai_mirror()
    return m.rotations(r, bandai_skeleton().parents).astype(np.float32), m.root(p).astype(np.float32)


def dump(net, spl, src: str, every: int, out: Path) -> Path:
    skel = net.skeleton
    rots, roots = shots(src)
    _, free, f = blocking.fill_blocked(net, spl, rots, roots, every)
    (m_r, m_p), (s_r, s_p), ds, (d_r, d_p) = f.model, f.spline, f.decisions, f.decided
    E = np.zeros((len(rots), len(GRID)))
    for i, w in enumerate(GRID):
        b_r, b_p = trust.blend_arrays(np.full(len(rots), w), m_r, m_p, s_r, s_p)
        E[:, i] = blocking.errors_cm(skel, b_r, b_p, rots, roots, free)
    path = out / f"d_{src}_{every}.npz"
    np.savez(
        path,
        E=E,
        decided=blocking.errors_cm(skel, d_r, d_p, rots, roots, free),
        em=np.array([[p["model_cm"] for p in d.probes] for d in ds]),
        es=np.array([[p["spline_cm"] for p in d.probes] for d in ds]),
        nov=np.array([np.nan if d.novelty_cm is None else d.novelty_cm for d in ds]),
        hole=min(p["gap"] for p in ds[0].probes),
    )
    return path


def summary(path: Path) -> str:
    d = np.load(path)
    probe = np.log((d["es"] + trust.EPS_CM) / (d["em"] + trust.EPS_CM)).mean(1)
    task = np.log(d["E"][:, 0] / d["E"][:, -1])
    better = min(d["E"][:, 0].mean(), d["E"][:, -1].mean())
    idx = np.digitize(probe, BINS) - 1
    cells = [
        f"{task[idx == b].mean():+.2f} ({(idx == b).sum()})" if (idx == b).any() else "-"
        for b in range(len(BINS) - 1)
    ]
    return (
        f"{path.stem[2:]}: novelty {np.nanmedian(d['nov']):.1f} cm, decided ÷ better "
        f"{d['decided'].mean() / better:.3f}, probe {probe.mean():+.2f} → task {task.mean():+.2f} | "
        + " | ".join(cells)
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--sources", default=",".join(blocking.SOURCES + ("mirrored",)))
    ap.add_argument("--every", default="8,10,15,20,30,40")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    net = load_inbetweener("default")
    spl = SplineInbetweener(net.skeleton)
    print("task log ratio in bins of the probes' mean log ratio:", BINS[1:-1])
    for src in a.sources.split(","):
        for every in (int(e) for e in a.every.split(",")):
            print(summary(dump(net, spl, src, every, a.out)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
