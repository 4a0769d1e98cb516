"""The trusted fill on blocking keys: long shots keyed every few frames, as an animator blocks.

The trust bench (:mod:`pipeline.bench.trust_bench`) keys every window at the protocol's 10 context
frames and one target, so its probes are holes in that run of keys. A blocked shot has no such
run: its probes leave single keys out (a gap twice as long as the shot's). Here each shot is
:data:`SHOT` frames of an eval clip (``eval``), of a CMU take on the model skeleton (``cmu``),
of an eval clip with posture offsets up to N° (``postureN``, e.g. ``posture30``), or of an
eval clip as a rig lacking joints brings it (``noshoulders``: no clavicles, ``nospine``: one
spine joint fewer; the joint in the model's typical pose, as the retarget gives it, and its
children keeping their world rotations), keyed every N frames; the model, the spline and the
decided fill (:mod:`pipeline.infer.trust`, per gap length) fill it, and each is scored by its
mean global joint-position error (cm, FK on the model skeleton) over the frames between the
keys.

The decided fill probes the library the model ships beside its network as the product's fill
does (``--no-library``: the network against the spline only). The ``cmu`` source holds the
library's own takes (subjects 1-3): measure other actors with :mod:`pipeline.bench.studio`.

``python -m pipeline.bench.blocking [--every 10,30] [--sources eval,cmu,posture30] [--limit N] [--model DIR] [--no-library] [--out DIR]``
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from pipeline.adapt.retarget import typical_local
from pipeline.arguments import Parser
from pipeline.bench import args as arg
from pipeline.bench.heldout import posture_degrees
from pipeline.bench.report import publish
from pipeline.data.protocol import windows_of
from pipeline.data.skeletons import bandai_skeleton
from pipeline.errors import TweenError
from pipeline.infer import trust
from pipeline.motion.rotations import quat_inv, quat_mul

SOURCES = ("eval", "cmu", "posture30", "posture10", "noshoulders", "nospine")
#: Rigs lacking joints the model skeleton has: the joints a source holds in the typical pose.
MISSING = {"noshoulders": ("Shoulder_L", "Shoulder_R"), "nospine": ("Spine",)}
#: Frames per shot, and the stride between shots cut from one clip.
SHOT, STRIDE = 181, 90


def shots(source: str, limit: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(rotations (N, SHOT, J, 4), roots (N, SHOT, 3)) of a source, on the model skeleton."""
    from pipeline.data.cache import load_split

    posture = posture_degrees(source)
    if source == "eval" or posture or source in MISSING:
        clips = load_split("eval", limit=limit)
        rots, roots = _windows((clips.clip(c) for c in range(len(clips))), source)
        if source in MISSING:
            rots = without_joints(rots, MISSING[source])
        if posture:
            from pipeline.motion.augment import posture_offsets

            rots = posture_offsets(rots, np.random.default_rng(0), posture, 1.0)
    elif source == "cmu":
        from pipeline.bench.heldout import cmu_files
        from pipeline.bench.long_gaps import cmu_on_model_skeleton

        files = cmu_files(None)[: limit or None]
        takes = (cmu_on_model_skeleton(f) for f in files)
        rots, roots = _windows(((m.rotations, m.root_positions) for m in takes), source)
    else:
        raise TweenError(
            f"--sources: unknown source {source!r} (one of eval, cmu, postureN, {', '.join(MISSING)})"
        )
    return rots.astype(np.float32), roots.astype(np.float32)


def without_joints(rots: np.ndarray, names) -> np.ndarray:
    """Local rotations (..., J, 4) as a rig without the joints ``names`` delivers them once
    retargeted (:meth:`pipeline.adapt.retarget.Retarget.to_model`): each such joint in the
    model's typical pose (:func:`~pipeline.adapt.retarget.typical_local`), its children
    turned so that their world rotations are unchanged (the bones below move only by the
    missing joint's own bone, a few cm)."""
    skel = bandai_skeleton()
    typical = typical_local()
    out = np.array(rots, copy=True)
    for name in names:
        j = skel.index(name)
        turn = quat_mul(quat_inv(typical[j]), out[..., j, :])
        for c in np.flatnonzero(np.asarray(skel.parents) == j):
            out[..., c, :] = quat_mul(turn, out[..., c, :])
        out[..., j, :] = typical[j]
    return out


def _windows(clips, source: str):
    try:
        return windows_of(clips, SHOT, STRIDE)
    except ValueError:  # no clip longer than a shot
        raise TweenError(f"{source}: no clip longer than {SHOT} frames (raise --limit)") from None


def errors_cm(skel, rot, root, true_rot, true_root, frames) -> np.ndarray:
    """(N,) mean world joint-position error (cm) of N shots over ``frames``."""
    return trust._errors_cm(skel, rot[:, frames], root[:, frames], true_rot[:, frames], true_root[:, frames])


def fill_blocked(model, spline, rots, roots, every: int, alternatives=()):
    """Shots keyed every ``every`` frames, filled three ways: (keys, free frames,
    :class:`pipeline.infer.trust.WindowFills`: the model's fill, the spline's, the decisions,
    the model's weight per shot and frame, the decided fill and which in-betweener each shot
    took). What :func:`evaluate` scores (and experiments/trust_sweep.py studies per shot).
    ``alternatives``: probed beside the model as the product's fill probes them (the library
    it ships)."""
    n = rots.shape[1]
    keys = np.r_[np.arange(0, n - 1, every), n - 1]
    free = np.setdiff1d(np.arange(n), keys)
    return keys, free, trust.trusted_fill_windows(model, spline, rots, roots, keys, alternatives=alternatives)


def evaluate(model, spline, rots, roots, every: int, alternatives=()) -> dict:
    """Mean error (cm) of model, spline (the animator's: ``spline``), the trusted fill's curve
    and the decided fill on shots keyed every ``every`` frames,
    the model's mean weight between the keys, the share of shots an alternative decided, and
    the seconds it took."""
    skel = model.skeleton
    t0 = time.perf_counter()
    keys, free, f = fill_blocked(model, trust.trusted_curve(skel), rots, roots, every, alternatives)
    fills = {"model": f.model, "spline": spline.fill_batch(rots, roots, keys), "curve": f.spline}
    fills["decided"] = f.decided
    err = {name: float(errors_cm(skel, r, p, rots, roots, free).mean()) for name, (r, p) in fills.items()}
    return {
        **err,
        "decided_over_better": err["decided"] / min(err["model"], err["spline"]),
        "decided_over_spline": err["decided"] / err["spline"],
        "decided_over_model": err["decided"] / err["model"],
        "mean_weight": float(f.weights[:, free].mean()),
        "probes": len(f.decisions[0].probes),
        "alternative_share": float(np.mean(f.chosen > 0)),
        "alternative_shares": [float(np.mean(f.chosen == k)) for k in range(1, len(alternatives) + 1)],
        "seconds": time.perf_counter() - t0,
    }


def run(sources=SOURCES, every=(10, 30), limit: int | None = None, model: str = "default",
        library: bool = True) -> dict:  # fmt: skip
    """``library``: the decided fill also probes the library the model ships beside its
    network (model.json's ``"library"``), as the product's fill does."""
    from pipeline.fill.api import FillOptions, probed_beside
    from pipeline.infer.api import load_inbetweener
    from pipeline.infer.spline import SplineInbetweener

    net = load_inbetweener(model)
    spline = SplineInbetweener(net.skeleton)
    # What the product's fill probes beside the network (--trust auto), chosen by its own rule.
    alternatives = probed_beside(FillOptions(model=model), net) if library else ()
    report: dict = {"model": net.name, "hash": net.model_hash, "shot": SHOT, "limit": limit, "sources": {}}
    report["beside"] = [{"name": a.name, "hash": a.model_hash} for a in alternatives]
    for src in sources:
        rots, roots = shots(src, limit)
        print(f"blocking bench: {src}, {len(rots)} shots of {SHOT} frames…", file=sys.stderr)
        report["sources"][src] = {
            "shots": int(len(rots)),
            "results": {int(e): evaluate(net, spline, rots, roots, int(e), alternatives) for e in every},
        }
    report["markdown"] = markdown(report)
    return report


def markdown(report: dict) -> str:
    beside = report["beside"]
    said = ", ".join(f"{b['name']} ({b['hash']})" for b in beside)
    heads = ["lib" if b["name"].startswith("library:") else b["name"] for b in beside]
    lines = [
        f"Model {report['model']} ({report['hash']})"
        + (f", with {said} probed beside it" if beside else ", the network against the spline only")
        + f"; shots of {report['shot']} frames keyed every N frames; mean joint-position error (cm) "
        "between the keys" + (f"; {', '.join(heads)}: the share of shots each decided." if beside else "."),
        "",
        "| source | keys every | shots | probes | model | spline | curve | decided | ÷ better | ÷ spline | ÷ model | w̄ |"
        + "".join(f" {h} |" for h in heads),
        "|---|---|---|---|---|---|---|---|---|---|---|---|" + "---|" * len(heads),
    ]
    for src, s in report["sources"].items():
        for e, r in s["results"].items():
            lines.append(
                f"| {src} | {e} | {s['shots']} | {r['probes']} | {r['model']:.3f} | {r['spline']:.3f} | "
                f"{r.get('curve', float('nan')):.3f} | {r['decided']:.3f} | {r['decided_over_better']:.3f} | "
                f"{r.get('decided_over_spline', float('nan')):.3f} | {r['decided_over_model']:.3f} | "
                f"{r['mean_weight']:.2f} |" + "".join(f" {x:.2f} |" for x in r["alternative_shares"])
            )
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = Parser(prog="python -m pipeline.bench.blocking", description=__doc__.splitlines()[0])
    ap.add_argument(
        "--every", type=arg.spacings, default=(10, 30), help="key spacings, comma-separated frames"
    )
    ap.add_argument("--sources", default=",".join(SOURCES), help="comma-separated: " + ", ".join(SOURCES))
    ap.add_argument("--limit", type=arg.count, default=None, help="first N eval clips / CMU takes")
    ap.add_argument("--model", default="default", help="the network: default, or a model folder")
    ap.add_argument("--no-library", action="store_true",
                    help="the network against the spline only (not the library the model ships beside it)")  # fmt: skip
    ap.add_argument("--out", type=Path, default=None, help="folder for blocking.json and blocking.md")
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    report = run(tuple(s for s in a.sources.split(",") if s), a.every, a.limit, a.model, not a.no_library)
    report["seconds"] = time.perf_counter() - t0
    publish(report, a.out, "blocking")
    return 0


if __name__ == "__main__":
    from pipeline.command import run_main
    from pipeline.data.cache_paths import cache_root

    run_main(main, log_dir=cache_root() / "logs")  # a bug's traceback goes there, as tween's
