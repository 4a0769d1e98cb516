"""Which tangents the trusted fill's curve takes: PCHIP, Catmull-Rom, or each where it fits.

The trusted fill falls back on a spline through the keys where its network is not trusted
(pipeline.infer.trust). Per key spacing, the world joint-position error between the keys
(cm) of the spline through the same keys with each kind of tangent, and its ratio to PCHIP
(the DCC default's clamped tangents, ``--model spline``):

- ``pchip``; ``catmull-rom`` (every interior key Catmull-Rom's slope, Maya's *Spline*,
  unbounded); ``unbounded`` (``adaptive`` without its Fritsch-Carlson bound); ``adaptive``
  (pipeline.infer.spline: Catmull-Rom's where keys are dense, within the bound, PCHIP's where
  sparse); ``cubic`` (not-a-knot C2).
- shots: the blocking bench's Bandai eval shots (181 frames; ``--stride N`` takes every Nth),
  keyed every N frames, and keyed pose to pose (``reducedN``: greedy key reduction against
  linear interpolation of the world joint positions, one key per N frames on average, as an
  animator keys extremes); the CMU takes of ``--subjects`` on their own 100-joint rig at
  30 fps (first 300 frames, leading glitch frames dropped, as pipeline.bench.studio); and
  motions that end in holds, the first 12 raise-up and 8 wave takes of Bandai dataset-2 by
  name (train and eval split alike: nothing here is trained), first 300 frames at 30 fps.

With ``--dcc``, three more columns: ``blender`` (Blender's own F-curve through the same keys:
its *Auto Clamped* handles, the mean of the two secants, flat at a channel's extremum and kept
within the neighbouring keys' values, handles 0.39 of the interval long, evaluated as the Bezier
it is; on the same quaternion channels), and PCHIP on other channels: ``pchip-rotvec`` (each
joint's rotation vector) and ``pchip-euler`` (ZXY Euler angles, unwrapped), as a DCC that
curves Euler channels does.

``python experiments/curve_tangents.py [--stride 4] [--subjects 5,6,7] [--dcc] [--out FILE.json]``
"""

from __future__ import annotations

import argparse
import json
import sys
from contextlib import contextmanager

import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.spatial.transform import Rotation

from pipeline.bench import blocking
from pipeline.bench.heldout import cmu_files
from pipeline.bench.studio import leading_glitch
from pipeline.data.skeletons import bandai_skeleton
from pipeline.data.split import shared_data_dir
from pipeline.infer import spline
from pipeline.motion.bvh import read_bvh
from pipeline.motion.clip import resample
from pipeline.motion.fk import fk

METHODS = ("pchip", "catmull-rom", "unbounded", "adaptive", "cubic")
#: ``--dcc``: the DCC's own curve, and PCHIP on the channels a DCC may curve instead.
DCC = ("blender", "pchip-rotvec", "pchip-euler")
#: Blender's handle length factor (its auto handles reach 2 / (2 * 2.5614) of the interval).
BLENDER_HANDLE = 2.5614
#: Module settings of pipeline.infer.spline each variant of ``adaptive`` runs with.
VARIANTS = {
    "catmull-rom": {"DENSE_S": 1e9, "SPARSE_S": 2e9, "SLOPE_BOUND": np.inf},
    "unbounded": {"SLOPE_BOUND": np.inf},
}


@contextmanager
def _settings(values: dict):
    """pipeline.infer.spline's module settings set to ``values`` for the block."""
    saved = {k: getattr(spline, k) for k in values}
    for k, v in values.items():
        setattr(spline, k, v)
    try:
        yield
    finally:
        for k, v in saved.items():
            setattr(spline, k, v)


def blender_fcurve(x: np.ndarray, y: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """(F, C) Blender's F-curve through keys ``y`` (K, C) at frames ``x`` (K,), read at
    ``frames``: auto-clamped handles, first and last flat (constant extrapolation)."""
    dx_a, dx_b = np.r_[x[1] - x[0], np.diff(x)], np.r_[np.diff(x), x[-1] - x[-2]]
    dy_a = np.vstack([y[1] - y[0], np.diff(y, axis=0)])
    dy_b = np.vstack([np.diff(y, axis=0), y[-1] - y[-2]])
    m = 0.5 * (dy_a / dx_a[:, None] + dy_b / dx_b[:, None])
    h_a = np.minimum(dx_a, 5 * dx_b) / BLENDER_HANDLE  # handle x-lengths
    h_b = np.minimum(dx_b, 5 * dx_a) / BLENDER_HANDLE
    left, right = y - m * h_a[:, None], y + m * h_b[:, None]
    prev, nxt = np.vstack([y[:1], y[:-1]]), np.vstack([y[1:], y[-1:]])
    d1, d2 = prev - y, nxt - y
    inner = np.zeros((len(x), 1), bool)
    inner[1:-1] = True
    turn = inner & (((d1 <= 0) & (d2 <= 0)) | ((d1 >= 0) & (d2 >= 0)))
    # A handle past its neighbouring key's value is clamped to it, the other handle aligned.
    lv = inner & ~turn & np.where(d1 <= 0, prev > left, prev < left)
    rv = inner & ~turn & np.where(d1 <= 0, nxt < right, nxt > right)
    left, right = np.where(lv, prev, left), np.where(rv, nxt, right)
    slope_l, slope_r = (y - left) / h_a[:, None], (right - y) / h_b[:, None]
    right = np.where(lv, y + slope_l * h_b[:, None], right)
    left = np.where(~lv & rv, y - slope_r * h_a[:, None], left)
    flat = turn.copy()
    flat[[0, -1]] = True
    left, right = np.where(flat, y, left), np.where(flat, y, right)
    seg = np.clip(np.searchsorted(x, frames, side="right") - 1, 0, len(x) - 2)
    x0, x3 = x[seg], x[seg + 1]
    x1, x2 = x0 + h_b[seg], x3 - h_a[seg + 1]
    lo, hi = np.zeros(len(frames)), np.ones(len(frames))
    for _ in range(40):  # the curve's parameter at each frame, by bisection (x is monotone)
        t = 0.5 * (lo + hi)
        xt = (1 - t) ** 3 * x0 + 3 * (1 - t) ** 2 * t * x1 + 3 * (1 - t) * t * t * x2 + t**3 * x3
        hi, lo = np.where(xt > frames, t, hi), np.where(xt > frames, lo, t)
    t = (0.5 * (lo + hi))[:, None]
    u = 1 - t
    return u**3 * y[seg] + 3 * u * u * t * right[seg] + 3 * u * t * t * left[seg + 1] + t**3 * y[seg + 1]


def _to_channels(q: np.ndarray, space: str) -> np.ndarray:
    if space == "euler":
        c = Rotation.from_quat(q.reshape(-1, 4)).as_euler("ZXY").reshape(*q.shape[:-1], 3)
        return np.unwrap(c, axis=0)
    s = np.linalg.norm(q[..., :3], axis=-1, keepdims=True)  # the rotation vector, continuous
    return q[..., :3] / np.maximum(s, 1e-12) * 2.0 * np.arctan2(s, q[..., 3:])  # along the keys


def _from_channels(c: np.ndarray, space: str) -> np.ndarray:
    if space == "euler":
        return Rotation.from_euler("ZXY", c.reshape(-1, 3)).as_quat().reshape(*c.shape[:-1], 4)
    a = np.linalg.norm(c, axis=-1, keepdims=True)
    return np.concatenate([c / np.maximum(a, 1e-12) * np.sin(a / 2), np.cos(a / 2)], -1)


def dcc_curve(method, rot, root, keys):
    """The ``--dcc`` columns: keys bitwise, held outside them, as pipeline.infer.spline."""
    keys = np.unique(keys)
    q = rot[keys].reshape(len(keys), -1, 4).astype(np.float64)
    step = np.where((q[1:] * q[:-1]).sum(-1) < 0, -1.0, 1.0)
    q *= np.concatenate([np.ones((1, q.shape[1])), np.cumprod(step, axis=0)])[..., None]
    space = method.partition("-")[2]
    c = _to_channels(q, space) if space else q
    y = np.concatenate([c.reshape(len(keys), -1), root[keys].reshape(len(keys), -1)], 1)
    frames = np.arange(keys[0], keys[-1] + 1, dtype=np.float64)
    x = keys.astype(np.float64)
    v = blender_fcurve(x, y, frames) if method == "blender" else PchipInterpolator(x, y)(frames)
    n = c.shape[1] * c.shape[2]
    cf = v[:, :n].reshape(len(frames), *c.shape[1:])
    qf = _from_channels(cf, space) if space else cf / np.linalg.norm(cf, axis=-1, keepdims=True)
    r, p = rot.astype(np.float64), root.astype(np.float64)
    r[keys[0] : keys[-1] + 1] = qf.reshape(len(frames), *rot.shape[1:])
    p[keys[0] : keys[-1] + 1] = v[:, n:].reshape(len(frames), *root.shape[1:])
    r[keys], p[keys] = rot[keys], root[keys]
    r[: keys[0]], r[keys[-1] + 1 :] = rot[keys[0]], rot[keys[-1]]
    p[: keys[0]], p[keys[-1] + 1 :] = root[keys[0]], root[keys[-1]]
    return r, p


def curve(method, rot, root, keys, fps=30.0):
    if method in DCC:
        return dcc_curve(method, rot, root, keys)
    if method in VARIANTS:
        with _settings(VARIANTS[method]):
            return spline.spline_keys(rot, root, keys, "adaptive", fps=fps)
    return spline.spline_keys(rot, root, keys, method, fps=fps)


def reduced_keys(pos: np.ndarray, mean_gap: int) -> np.ndarray:
    """Greedy key reduction: from the first and last frame, add the frame the linear
    interpolation of world positions (T, J, 3) misses most, until one key per ``mean_gap``."""
    n = len(pos)
    keys = [0, n - 1]
    while len(keys) < max(2, round((n - 1) / mean_gap) + 1):
        ks = sorted(keys)
        best, at = -1.0, None
        for a, b in zip(ks[:-1], ks[1:], strict=True):
            if b - a < 2:
                continue
            w = ((np.arange(a + 1, b) - a) / (b - a))[:, None, None]
            miss = np.linalg.norm(pos[a + 1 : b] - ((1 - w) * pos[a] + w * pos[b]), axis=-1).mean(-1)
            if miss.max() > best:
                best, at = float(miss.max()), a + 1 + int(np.argmax(miss))
        keys.append(at)
    return np.array(sorted(keys))


def bandai(stride: int) -> dict:
    skel = bandai_skeleton()
    rots, roots = blocking.shots("eval")
    rots, roots = rots[::stride].astype(np.float64), roots[::stride].astype(np.float64)
    n = rots.shape[1]
    out = {}
    for layout in (
        "every5",
        "every10",
        "every15",
        "every20",
        "every30",
        "reduced8",
        "reduced10",
        "reduced15",
    ):
        print(f"bandai eval: {layout}…", file=sys.stderr)
        total = dict.fromkeys(METHODS, 0.0)
        for i in range(len(rots)):
            if layout.startswith("every"):
                e = int(layout[5:])
                keys = np.r_[np.arange(0, n - 1, e), n - 1]
            else:
                keys = reduced_keys(fk(rots[i], roots[i], skel.parents, skel.offsets)[1], int(layout[7:]))
            free = np.setdiff1d(np.arange(n), keys)
            for m in METHODS:
                r, p = curve(m, rots[i], roots[i], keys)
                total[m] += float(
                    blocking.errors_cm(skel, r[None], p[None], rots[i : i + 1], roots[i : i + 1], free)[0]
                )
        out[layout] = {m: total[m] / len(rots) for m in METHODS}
    return {"shots": int(len(rots)), "cm": out}


def holds() -> dict:
    """The raise-up and wave takes: motions that end in holds."""
    folder = shared_data_dir() / "bandai_namco" / "dataset-2"
    files = sorted(folder.glob("dataset-2_raise-up-*"))[:12] + sorted(folder.glob("dataset-2_wave-*"))[:8]
    return takes(files, (10, 15, 30))


def cmu(subjects) -> dict:
    return takes(cmu_files(subjects), (10, 15, 20, 30))


def takes(files, spacings) -> dict:
    """Per key spacing, each method's mean error (cm) over ``files`` on their own rig."""
    out: dict = {}
    for f in files:
        print(f"take: {f.name}…", file=sys.stderr)
        motion = read_bvh(f)
        cut = leading_glitch(motion)
        motion = motion.slice(cut, len(motion)) if cut else motion
        at30 = resample(motion, 30.0)
        at30 = at30.slice(0, min(len(at30), 300))
        T, scale = len(at30), at30.skeleton.meters_per_unit * 100.0
        truth = at30.positions()
        for e in spacings:
            keys = np.unique(np.r_[np.arange(0, T, e), T - 1])
            free = np.setdiff1d(np.arange(T), keys)
            row = out.setdefault(f"every{e}", {m: [0.0, 0] for m in METHODS})
            for m in METHODS:
                r, p = curve(m, at30.rotations, at30.root_positions, keys)
                pos = type(at30)(at30.skeleton, r, p, at30.fps).positions()
                err = np.linalg.norm(pos[free] - truth[free], axis=-1) * scale
                row[m][0] += float(err.sum())
                row[m][1] += int(err.size)
    return {"takes": len(files), "cm": {k: {m: s / n for m, (s, n) in v.items()} for k, v in out.items()}}


def table(name: str, cm: dict) -> str:
    lines = [
        f"**{name}** (cm; ÷ PCHIP)",
        "",
        "| keys | " + " | ".join(METHODS) + " |",
        "|---|" + "---|" * len(METHODS),
    ]
    for layout, row in cm.items():
        cells = [f"{row[m]:.3f} ({row[m] / row['pchip']:.3f})" for m in METHODS]
        lines.append(f"| {layout} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stride", type=int, default=4, help="every Nth Bandai eval shot")
    ap.add_argument("--subjects", default="5,6,7", help="CMU subjects, comma-separated")
    ap.add_argument("--out", default=None, help="write the results as JSON here")
    ap.add_argument("--dcc", action="store_true", help="add Blender's own curve and PCHIP on other channels")
    a = ap.parse_args(argv)
    if a.dcc:
        global METHODS
        METHODS = ("pchip", "adaptive", *DCC)
    res = {
        "thresholds_s": [spline.DENSE_S, spline.SPARSE_S],
        "slope_bound": spline.SLOPE_BOUND,
        "bandai_eval": bandai(a.stride),
        "cmu": cmu(tuple(int(s) for s in a.subjects.split(","))),
        "holds": holds(),
    }
    res["markdown"] = table(f"Bandai eval, {res['bandai_eval']['shots']} shots", res["bandai_eval"]["cm"])
    res["markdown"] += "\n" + table(
        f"CMU subjects {a.subjects}, {res['cmu']['takes']} takes", res["cmu"]["cm"]
    )
    res["markdown"] += "\n" + table(
        f"Bandai raise-up and wave takes, {res['holds']['takes']}", res["holds"]["cm"]
    )
    print(res["markdown"])
    if a.out:
        with open(a.out, "w") as fh:
            json.dump(res, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
