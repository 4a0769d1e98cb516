"""The studio bench: another studio's takes through the product's own path, scored on its rig.

What a studio does with the tool, end to end: a take of its own rig (here the CMU takes of
``../shared/data/cmu_iclone``: other actors and capture, a 100-joint Character Creator rig) is
converted to a blocked UsdSkel shot (``tween convert --fps 30 --keys-every N``), filled through
the fill API (``tween fill-local``; the default with its trusted fill, and the alternatives),
and the review stage's joints are compared with the capture **in the rig's own world joint
positions** (cm, between the keys): every joint of the rig, and the joints that map to the
model's. Nothing here goes through the model skeleton except what the fill itself does.

Methods: ``default`` (the shipped fill: network, trust decided from the shot), ``network``
(the same model with ``--trust model``), ``spline`` (the animator's own curves), ``interp``;
and, asked for by name, ``curve`` (the same model with ``--trust spline``: the trusted fill's
curve alone, pipeline.infer.trust.trusted_curve).

``python -m pipeline.bench.studio [--every 10,30] [--subjects 5,6,7] [--limit N]
[--max-frames 300] [--fps 30] [--methods default,network,spline,interp] [--keep-glitches] [--out DIR]``
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pipeline.adapt.mapping import map_joints
from pipeline.arguments import Parser
from pipeline.bench import args as arg
from pipeline.bench.heldout import cmu_files
from pipeline.bench.report import publish
from pipeline.fill.api import FillOptions, fill_shot
from pipeline.motion.bvh import read_bvh
from pipeline.motion.clip import resample
from pipeline.usd.convert import write_shot

METHODS = ("default", "network", "spline", "interp")
#: (model, trust) of each method's fill; ``curve`` runs only when asked for.
_FILL = {
    "default": ("default", "auto"),
    "network": ("default", "model"),
    "spline": ("spline", "auto"),
    "interp": ("interp", "auto"),
    "curve": ("default", "spline"),
}
FPS = 30.0


def review_positions(review: str, n_frames: int) -> np.ndarray:
    """(T, J, 3) world positions (cm) of every joint of the shot's one skeleton, in the
    order of its ``joints``, from the composed review stage."""
    from pxr import Usd, UsdGeom, UsdSkel

    stage = Usd.Stage.Open(review)
    cache = UsdSkel.Cache()
    roots = [p for p in stage.Traverse() if p.IsA(UsdSkel.Root)]
    cache.Populate(UsdSkel.Root(roots[0]), Usd.PrimDefaultPredicate)
    skel = next(p for p in Usd.PrimRange(roots[0]) if p.IsA(UsdSkel.Skeleton))
    query = cache.GetSkelQuery(UsdSkel.Skeleton(skel))
    xf = UsdGeom.XformCache()
    start = stage.GetStartTimeCode()
    out = np.empty((n_frames, len(query.GetJointOrder()), 3))
    for i in range(n_frames):
        t = Usd.TimeCode(start + i)
        xf.SetTime(t)
        world = np.array(xf.GetLocalToWorldTransform(skel))
        m = np.array(query.ComputeJointSkelTransforms(t))
        out[i] = m[:, 3, :3] @ world[:3, :3] + world[3, :3]
    return out * UsdGeom.GetStageMetersPerUnit(stage) * 100.0


#: A root move (cm) between two source frames that no capture makes: a glitch frame.
GLITCH_CM = 50.0


def leading_glitch(motion) -> int:
    """Source frames to drop at the start of a take: up to the last root jump of more than
    GLITCH_CM in its first second (ten CMU takes of subject 7 start with one frame 1.7-2.7 m
    away from the next, which would otherwise dominate their first gap's error); 0 if none."""
    root = motion.root_positions * motion.skeleton.meters_per_unit * 100.0
    head = int(min(len(root) - 1, round(motion.fps)))
    jumps = np.flatnonzero(np.linalg.norm(np.diff(root[: head + 1], axis=0), axis=-1) > GLITCH_CM)
    return int(jumps[-1]) + 1 if len(jumps) else 0


def evaluate_take(
    path: Path,
    every: int,
    methods,
    work: Path,
    max_frames: int | None,
    trim: bool = True,
    fps: float = 30.0,
    fills: dict | None = None,
) -> dict:
    """Per method: summed joint errors (cm) and counts over the take's frames between keys,
    for all joints and for the joints mapped to the model's; and each default fill's trust.
    ``trim``: leading glitch frames dropped (:func:`leading_glitch`); ``fps``: the shot's rate
    (0: the take's own); ``fills``: each method's FillOptions fields (default: ``_FILL``'s
    model and trust)."""
    motion = read_bvh(path)
    cut = leading_glitch(motion) if trim else 0
    if cut:
        motion = motion.slice(cut, len(motion))
    fps = float(fps or motion.fps)
    at30 = resample(motion, fps)
    if max_frames and len(at30) > max_frames:
        motion = motion.slice(0, int(np.ceil((max_frames - 1) * motion.fps / fps)) + 1)
        at30 = resample(motion, fps)
    T = len(at30)
    truth = at30.positions() * at30.skeleton.meters_per_unit * 100.0
    mapped = sorted(map_joints(tuple(at30.skeleton.names), at30.skeleton.parents).values())
    keys = np.r_[np.arange(0, T, every), T - 1]
    inside = np.setdiff1d(np.arange(T), keys)
    shot = Path(
        write_shot(motion, work / f"{path.name.split('.')[0]}_{every}.usda", fps=fps, keys_every=every)
    )
    res: dict = {"frames": int(T), "inside": int(len(inside)), "trimmed": cut, "methods": {}}
    for m in methods:
        fields = (fills or {}).get(m) or dict(zip(("model", "trust"), _FILL[m], strict=True))
        out = fill_shot(str(shot), FillOptions(**fields, out_dir=str(work / f"{shot.stem}_{m}")))
        pos = review_positions(out["review"], T)
        err = np.linalg.norm(pos[inside] - truth[inside], axis=-1)
        row = {"all_sum": float(err.sum()), "all_n": int(err.size)}
        row |= {"mapped_sum": float(err[:, mapped].sum()), "mapped_n": int(err[:, mapped].size)}
        d = next(iter((out.get("trust") or {}).values()), None)
        if d is not None:
            row["trust"] = {k: d.get(k) for k in ("choice", "weight", "novelty_cm", "source")}
            if len(d.get("candidates") or []) > 1:  # each probed in-betweener's score
                row["trust"]["scores"] = {c["name"]: c["score"] for c in d["candidates"]}
            if d.get("library"):
                gaps = d["library"]["gaps"]
                row["trust"]["library_share"] = round(float(np.mean([g["share"] for g in gaps])), 4)
        res["methods"][m] = row
    return res


def run(
    every=(10, 30),
    subjects=None,
    limit=None,
    methods=METHODS,
    max_frames: int | None = 300,
    trim: bool = True,
    fps: float = FPS,
) -> dict:
    files = cmu_files(subjects)[: limit or None]
    report: dict = {"every": list(every), "takes": [f.name for f in files], "max_frames": max_frames}
    report.update(trim=trim, fps=fps)
    t0 = time.perf_counter()
    per: dict = {int(e): {} for e in every}
    with tempfile.TemporaryDirectory(prefix="tween-studio-") as tmp:
        for i, f in enumerate(files):
            for e in every:
                print(f"studio bench: take {i + 1}/{len(files)} {f.name}, keys every {e}…", file=sys.stderr)
                per[int(e)][f.name] = evaluate_take(f, int(e), methods, Path(tmp), max_frames, trim, fps)
    report["per_take"] = per
    report["error_cm"] = {
        e: {
            m: {
                part: sum(t["methods"][m][f"{part}_sum"] for t in takes.values())
                / max(1, sum(t["methods"][m][f"{part}_n"] for t in takes.values()))
                for part in ("all", "mapped")
            }
            for m in methods
        }
        for e, takes in per.items()
    }
    report["seconds"] = time.perf_counter() - t0
    report["markdown"] = markdown(report, methods)
    return report


def markdown(rep: dict, methods) -> str:
    trimmed = sorted({n for takes in rep["per_take"].values() for n, t in takes.items() if t["trimmed"]})
    lines = [
        f"{len(rep['takes'])} CMU takes (first {rep['max_frames']} frames at "
        f"{rep.get('fps') or 'their own'} fps each), converted, "
        "blocked, filled and scored on their own rig: mean world joint error (cm) between the keys.",
        (
            f"Leading glitch frames dropped from {len(trimmed)} take(s): {', '.join(trimmed)}."
            if rep.get("trim", True)
            else "Takes as they are (no glitch frame dropped)."
        ),
        "",
        "| keys every | joints | " + " | ".join(methods) + " | default ÷ better of network, spline |",
        "|---|---|" + "---|" * len(methods) + "---|",
    ]
    for e, table in rep["error_cm"].items():
        for part in ("mapped", "all"):
            vals = [table[m][part] for m in methods]
            better = [table[m][part] for m in ("network", "spline") if m in table]
            ratio = table["default"][part] / min(better) if "default" in table and better else float("nan")
            lines.append(f"| {e} | {part} | " + " | ".join(f"{v:.3f}" for v in vals) + f" | {ratio:.3f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = Parser(prog="python -m pipeline.bench.studio", description=__doc__.splitlines()[0])
    ap.add_argument(
        "--every",
        type=arg.spacings,
        default=(10, 30),
        help="key spacings, comma-separated frames (of the shot)",
    )
    ap.add_argument(
        "--subjects", type=arg.subjects, default=None, help="CMU subjects, e.g. 5,6,7 (default: all)"
    )
    ap.add_argument("--limit", type=arg.count, default=None, help="first N takes")
    ap.add_argument(
        "--max-frames",
        type=arg.frames_or_all,
        default=300,
        help="frames of each take at the shot rate (0: all)",
    )
    ap.add_argument("--methods", default=",".join(METHODS), help="comma-separated: " + ", ".join(_FILL))
    ap.add_argument("--out", type=Path, default=None, help="folder for studio.json and studio.md")
    ap.add_argument("--keep-glitches", action="store_true", help="keep takes' leading glitch frames")
    ap.add_argument(
        "--fps", type=arg.rate, default=FPS, help="the shots' rate (tween convert --fps; 0: the take's)"
    )
    a = ap.parse_args(argv)
    methods = tuple(m for m in a.methods.split(",") if m)
    bad = [m for m in methods if m not in _FILL]
    if bad:
        ap.error(f"--methods: unknown {', '.join(bad)} (one of {', '.join(_FILL)})")
    rep = run(a.every, a.subjects, a.limit, methods, a.max_frames or None, not a.keep_glitches, a.fps)
    publish(rep, a.out, "studio")
    return 0


if __name__ == "__main__":
    from pipeline.command import run_main
    from pipeline.data.cache_paths import cache_root

    run_main(main, log_dir=cache_root() / "logs")  # a bug's traceback goes there, as tween's
