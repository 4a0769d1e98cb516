"""The trusted fill on the benchmark: model, spline, interpolation and the decided fill.

Every window is one shot, keyed at its 10 context frames and its target: the probes of
:mod:`pipeline.infer.trust` see those keys only, and each window gets its own decision. The
decided fill is :func:`~pipeline.infer.trust.trusted_fill_windows`: trusted_fill's steps on
the model skeleton, batched over windows that share their keys; the benches that fill shots
(``pipeline.bench.studio``, ``pipeline.bench.rig_variants``) go through the product's own
fill, trusted_fill on the rig. On
the protocol's eval windows and on every held-out source (``cmu``: other actors; ``posture30``:
posture offsets up to 30°; ``mirrored``: left/right mirror images), L2P and L2Q per transition
length of the five fills (``curve``: the spline through the same keys with the trusted fill's
tangents, what it falls back on), the decided fill's ratio to the better of model and spline and to
the model, how often each choice was made and the time it took.

``python -m pipeline.bench.trust_bench [--limit N] [--sources eval,cmu] [--out DIR] [--dump F.npz] [--model DIR]``
(``--limit``: the first N eval clips, and at most 2N CMU windows evenly spaced over the
takes; ``--dump``: per-window probe errors and per-window L2P of blends at w = 0, ¼, ½, ¾, 1,
what the thresholds of the decision were tuned on).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from pipeline.arguments import Parser
from pipeline.bench import args as arg
from pipeline.bench.heldout import parse_source, posture_degrees
from pipeline.bench.report import publish
from pipeline.data.protocol import CONTEXT, TRANSITIONS, global_positions, position_stats
from pipeline.errors import TweenError
from pipeline.infer import novelty, trust

SOURCES = ("eval", "cmu", "posture30", "mirrored")
#: ``spline``: the DCC default's clamped tangents (the animator's curve); ``curve``: the trusted
#: fill's own curve (pipeline.infer.trust.trusted_curve), which it blends the model with.
METHODS = ("interp", "spline", "curve", "model", "decided")
GRID = (0.0, 0.25, 0.5, 0.75, 1.0)


def source_windows(source: str, limit: int | None = None):
    """(rotations (N, 65, J, 4), roots (N, 65, 3)) of a source, normalised as the protocol's."""
    from pipeline.bench.run import test_windows

    if source == "eval":
        return test_windows(limit)
    if source.partition(":")[0] == "cmu":
        r, p = test_windows(source=source)
        if limit:
            idx = np.unique(np.linspace(0, len(r) - 1, min(len(r), 2 * limit)).astype(int))
            r, p = r[idx], p[idx]
        return r, p
    if source == "mirrored":
        return test_windows(limit, mirrored=True)
    if posture_degrees(source) is not None:
        return test_windows(limit, posture=posture_degrees(source))
    raise TweenError(f"--sources: unknown source {source!r} (one of {', '.join(SOURCES)})")


def parse_sources(text: str) -> tuple[str, ...]:
    """``--sources``: comma-separated, a ``cmu:`` source keeping the subject numbers after it
    (``eval,cmu:5,6,7,posture30``); each checked before anything runs (TweenError)."""
    out: list[str] = []
    for part in (p.strip() for p in text.split(",") if p.strip()):
        if part.isdigit() and out and out[-1].startswith("cmu:"):
            out[-1] += "," + part
        else:
            out.append(part)
    for src in out:
        if src.partition(":")[0] == "cmu":
            parse_source(src)
        elif src not in SOURCES and posture_degrees(src) is None:
            raise TweenError(
                f"--sources: unknown source {src!r} (one of {', '.join(SOURCES)}, cmu:5,6,7, postureN)"
            )
    return tuple(out)


def _per_window_l2p(gp_p, gp_t, mean, std) -> np.ndarray:
    n, t = gp_p.shape[:2]
    a = (gp_p.reshape(n, t, -1) - mean) / std
    b = (gp_t.reshape(n, t, -1) - mean) / std
    return np.linalg.norm(a - b, axis=-1).mean(axis=1)


def _per_window_l2q(gq_p, gq_t) -> np.ndarray:
    d = (gq_p - gq_t).reshape(gq_p.shape[0], gq_p.shape[1], -1)
    return np.linalg.norm(d, axis=-1).mean(axis=1)


def _shots(rots, roots, T: int):
    """The windows as shots: context, then the target held (frames between are not keys)."""
    tgt = CONTEXT + T
    r = np.concatenate([rots[:, :CONTEXT], np.repeat(rots[:, tgt : tgt + 1], T + 1, axis=1)], axis=1)
    p = np.concatenate([roots[:, :CONTEXT], np.repeat(roots[:, tgt : tgt + 1], T + 1, axis=1)], axis=1)
    return r, p, np.r_[np.arange(CONTEXT), tgt]


def evaluate_source(model, spline, rots, roots, mean, std, transitions=TRANSITIONS, dump=None,
                    alternatives=()) -> dict:  # fmt: skip
    """Per transition length: L2P / L2Q of each method (``spline``: the animator's, filled by
    ``spline``), choices (and the share of windows each
    of ``alternatives`` decided) and seconds."""
    from pipeline.infer.interp import interpolate_between

    out = {}
    cache: dict = {}  # context probes are the same for every transition length
    for T in transitions:
        sl = slice(CONTEXT, CONTEXT + T)
        rr, pp, keys = _shots(rots, roots, T)
        wf = trust.trusted_fill_windows(model, trust.trusted_curve(model.skeleton), rr, pp, keys, cache,
                                        alternatives)  # fmt: skip
        (m_r, m_p), (s_r, s_p), (d_r, d_p), decisions = wf.model, wf.spline, wf.decided, wf.decisions
        a_r, a_p = spline.fill_batch(rr, pp, keys)
        w = np.array([d.weight for d in decisions])
        i_r, i_p = interpolate_between(
            rots[:, CONTEXT - 1], rots[:, CONTEXT + T], roots[:, CONTEXT - 1], roots[:, CONTEXT + T], T
        )
        i_r, i_p = np.moveaxis(i_r, 0, 1), np.moveaxis(i_p, 0, 1)
        gq_t, gp_t = global_positions(rots[:, sl], roots[:, sl])
        fills = {"interp": (i_r, i_p), "spline": (a_r[:, sl], a_p[:, sl]), "curve": (s_r[:, sl], s_p[:, sl])}
        fills["model"] = (m_r[:, sl], m_p[:, sl])
        fills["decided"] = (d_r[:, sl], d_p[:, sl])
        res = {}
        for name, (r, p) in fills.items():
            gq, gp = global_positions(r, p)
            res[name] = {
                "L2P": float(_per_window_l2p(gp, gp_t, mean, std).mean()),
                "L2Q": float(_per_window_l2q(gq, gq_t).mean()),
            }
        choices = [d.choice for d in decisions]
        res["choices"] = {c: choices.count(c) for c in trust.CHOICES}
        res["mean_weight"] = float(w.mean())
        res["alternative_shares"] = [float(np.mean(wf.chosen == k)) for k in range(1, len(alternatives) + 1)]
        res["probes"] = len(decisions[0].probes)
        res["seconds"] = wf.seconds
        if dump is not None:
            grid = []
            for g in GRID:
                b_r, b_p = trust.blend_arrays(g, m_r[:, sl], m_p[:, sl], s_r[:, sl], s_p[:, sl])
                grid.append(_per_window_l2p(global_positions(b_r, b_p)[1], gp_t, mean, std))
            em = np.array([[p["model_cm"] for p in d.probes] for d in decisions])
            es = np.array([[p["spline_cm"] for p in d.probes] for d in decisions])
            dump[T] = {
                "l2p_grid": np.stack(grid, 1),
                "em": em,
                "es": es,
                "kinds": [p["kind"] for p in decisions[0].probes],
            }
        out[T] = res
    return out


def run_trust_bench(
    sources=SOURCES,
    limit: int | None = None,
    transitions=TRANSITIONS,
    dump: str | None = None,
    model: str = "default",
    beside: bool = False,
) -> dict:
    """Every source's table (see the module docstring): ``{"sources": {source: {"windows": N,
    "seconds": s, "results": {T: {method: {"L2P", "L2Q"}, "choices", ...}}}}, "markdown": str}``.
    ``beside``: the decided fill also probes what the fill probes beside the network (the
    library and networks its model folder ships; pipeline.fill.api.probed_beside)."""
    from pipeline.data.cache import load_split
    from pipeline.fill.api import FillOptions, probed_beside
    from pipeline.infer.api import load_inbetweener
    from pipeline.infer.spline import SplineInbetweener

    mean, std = position_stats(load_split("train"))
    model, name = load_inbetweener(model), model
    spline = SplineInbetweener(model.skeleton)
    alternatives = probed_beside(FillOptions(model=name), model) if beside else ()
    report: dict = {"model": model.name, "hash": model.model_hash, "limit": limit, "sources": {}}
    report["beside"] = [{"name": a.name, "hash": a.model_hash} for a in alternatives]
    dumps = {}
    for src in sources:
        t0 = time.perf_counter()
        rots, roots = source_windows(src, limit)
        print(f"trust bench: {src}, {len(rots)} windows…", file=sys.stderr)
        d = {} if dump else None
        results = evaluate_source(model, spline, rots, roots, mean, std, transitions, d, alternatives)
        report["sources"][src] = {
            "windows": int(len(rots)),
            "seconds": time.perf_counter() - t0,
            "results": results,
        }
        if dump:
            dumps[src] = d
    report["constants"] = {
        k: getattr(trust, k)
        for k in (
            "MIN_GAP",
            "MAX_PROBES",
            "RUN_SIDE",
            "EPS_CM",
            "THRESHOLD",
            "LONG_GAP",
            "BAND",
            "PRIOR_PROBES",
        )
    } | {k: getattr(novelty, k) for k in ("FAMILIAR_CM", "NOVEL_CM")}
    report["markdown"] = markdown(report, transitions)
    if dump:
        flat = {}
        for src, per_t in dumps.items():
            for T, v in per_t.items():
                for k in ("l2p_grid", "em", "es"):
                    flat[f"{src}/{T}/{k}"] = v[k]
                flat[f"{src}/{T}/kinds"] = np.array(v["kinds"])
        np.savez(dump, **flat)
    return report


def markdown(report: dict, transitions=TRANSITIONS) -> str:
    beside = report.get("beside") or []
    said = ", ".join(f"{b['name']} ({b['hash']})" for b in beside)
    lines = [
        f"Model {report['model']} ({report['hash']})"
        + (
            f", with {said} probed beside it (each one's share of windows after the choices)"
            if beside
            else ""
        )
        + "; each window one shot keyed at its context and target.",
        "",
    ]
    head = "| source | method | " + " | ".join(str(t) for t in transitions) + " |"
    sep = "|---|---|" + "---|" * len(transitions)
    for metric in ("L2P", "L2Q"):
        lines += [f"**{metric}**", "", head, sep]
        for src, s in report["sources"].items():
            r = s["results"]
            for m in METHODS:
                lines.append(
                    f"| {src} | {m} | " + " | ".join(f"{r[t][m][metric]:.4f}" for t in transitions) + " |"
                )
            best = [min(r[t]["model"][metric], r[t]["spline"][metric]) for t in transitions]
            cells = [f"{r[t]['decided'][metric] / b:.3f}" for t, b in zip(transitions, best, strict=True)]
            lines.append(f"| {src} | decided ÷ better of model, spline | " + " | ".join(cells) + " |")
            cells = [f"{r[t]['decided'][metric] / r[t]['model'][metric]:.3f}" for t in transitions]
            lines.append(f"| {src} | decided ÷ model | " + " | ".join(cells) + " |")
        lines.append("")
    lines += ["**Choices** (model / blend / spline windows; mean weight; probes per shot)", "", head, sep]
    for src, s in report["sources"].items():
        r = s["results"]
        cells = [
            f"{r[t]['choices']['model']}/{r[t]['choices']['blend']}/{r[t]['choices']['spline']}; "
            f"w̄ {r[t]['mean_weight']:.2f}; {r[t]['probes']}"
            + "".join(f"; {x:.2f}" for x in r[t].get("alternative_shares") or [])
            for t in transitions
        ]
        lines.append(f"| {src} | choices | " + " | ".join(cells) + " |")
    lines += ["", "| source | windows | seconds (all) | model fill s | probe s |", "|---|---|---|---|---|"]
    for src, s in report["sources"].items():
        r = s["results"]
        mf = sum(r[t]["seconds"]["model_fill"] for t in transitions)
        pr = sum(r[t]["seconds"]["probes"] for t in transitions)
        lines.append(f"| {src} | {s['windows']} | {s['seconds']:.0f} | {mf:.0f} | {pr:.0f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = Parser(prog="python -m pipeline.bench.trust_bench", description=__doc__.splitlines()[0])
    ap.add_argument(
        "--limit", type=arg.count, default=None, help="first N eval clips (and at most 2N CMU windows)"
    )
    ap.add_argument("--sources", default=",".join(SOURCES), help="comma-separated: " + ", ".join(SOURCES))
    ap.add_argument("--out", type=Path, default=None, help="folder for trust.json and trust.md")
    ap.add_argument("--dump", default=None, help="npz of per-window probe errors and blend L2P (tuning)")
    ap.add_argument("--model", default="default", help="the network: default, or a model folder")
    ap.add_argument("--beside", action="store_true",
                    help="also probe what the fill probes beside the network (its library and networks)")  # fmt: skip
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    sources = parse_sources(a.sources)
    report = run_trust_bench(sources, a.limit, dump=a.dump, model=a.model, beside=a.beside)
    report["seconds"] = time.perf_counter() - t0
    publish(report, a.out, "trust")
    return 0


if __name__ == "__main__":
    from pipeline.command import run_main
    from pipeline.data.cache_paths import cache_root

    run_main(main, log_dir=cache_root() / "logs")  # a bug's traceback goes there, as tween's
