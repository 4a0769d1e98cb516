"""``tween bench``: the full protocol over a set of methods, as JSON and Markdown."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from pipeline.bench import metrics
from pipeline.bench.methods import Method, resolve
from pipeline.bench.outputs import write_outputs
from pipeline.data.cache import load_split
from pipeline.data.protocol import (
    CONTEXT,
    TEST_STRIDE,
    TEST_WINDOW,
    TRANSITIONS,
    cut_windows,
    global_positions,
    normalize_windows,
    position_stats,
    window_starts,
)
from pipeline.data.skeletons import FOOT_JOINTS, bandai_mirror, bandai_skeleton
from pipeline.errors import TweenError
from pipeline.motion.augment import posture_offsets

METRICS = ("L2Q", "L2P", "NPSS", "MPJPE", "skate")


def test_windows(
    limit: int | None = None, mirrored: bool = False, posture: float = 0.0, source: str = "eval"
):
    """The normalised eval windows (``limit`` clips only, for quick checks; of the CMU
    takes, the first ``limit`` takes).

    ``mirrored``: each window's left/right mirror image instead, a robustness check outside
    the protocol (the actors' handedness and gait asymmetries are reversed; the mirror keeps
    the window centred and facing +X at frame 9, so the protocol's normalisation still holds).
    ``source="cmu"``: windows of the CMU takes instead (``pipeline.bench.heldout``);
    ``"cmu:5,6,7"``: of those CMU subjects only.
    ``posture``: every window's joints get constant offsets of up to this many degrees (fixed
    seed), as a rig set up differently from the actors' would carry them; the windows are
    normalised again afterwards. Also outside the protocol.
    """
    if source.partition(":")[0] == "cmu":
        from pipeline.bench.heldout import cmu_windows, parse_source

        rots, roots = cmu_windows(parse_source(source)[1], limit)
    elif source == "eval":
        clips = load_split("eval", limit=limit)
        if not any(len(window_starts(n, TEST_WINDOW, TEST_STRIDE)) for n in clips.lengths):
            raise TweenError(
                f"eval split: no {TEST_WINDOW}-frame window in the first {len(clips)} clip(s) "
                f"(a clip needs more than {TEST_WINDOW} frames); raise --limit"
            )
        rots, roots = normalize_windows(*cut_windows(clips, TEST_WINDOW, TEST_STRIDE))
    else:
        raise ValueError(f"unknown window source {source!r} (eval, cmu or cmu:SUBJECTS)")
    if mirrored:
        m = bandai_mirror()
        rots = m.rotations(rots, bandai_skeleton().parents).astype(rots.dtype)
        roots = m.root(roots).astype(roots.dtype)
    if posture > 0:
        rots = posture_offsets(rots, np.random.default_rng(0), posture, 1.0)
        rots, roots = normalize_windows(rots, roots)
    return rots, roots


def evaluate(method: Method, rots, roots, mean, std, transitions=TRANSITIONS) -> dict:
    """Metrics per transition length for one method on normalised windows."""
    skel = bandai_skeleton()
    feet = [skel.index(n) for n in FOOT_JOINTS]
    out = {}
    for T in transitions:
        tgt = CONTEXT + T
        t0 = time.perf_counter()
        p_rot, p_root = method(rots[:, :CONTEXT], roots[:, :CONTEXT], rots[:, tgt], roots[:, tgt], T)
        seconds = time.perf_counter() - t0
        gq_p, gp_p = global_positions(p_rot, p_root)
        gq_t, gp_t = global_positions(rots[:, CONTEXT:tgt], roots[:, CONTEXT:tgt])
        _, prev = global_positions(rots[:, CONTEXT - 1], roots[:, CONTEXT - 1])
        skate, n_contacts = metrics.foot_skate(gp_p, gp_t, prev, prev, feet)
        skate_gt, _ = metrics.foot_skate(gp_t, gp_t, prev, prev, feet)
        out[T] = {
            "L2Q": metrics.l2q(gq_p, gq_t),
            "L2P": metrics.l2p(gp_p, gp_t, mean, std),
            "NPSS": metrics.npss(gq_p, gq_t),
            "MPJPE": metrics.mpjpe(gp_p, gp_t),
            "skate": skate,
            "skate_gt": skate_gt,
            "contacts": n_contacts,
            "seconds": seconds,
        }
    return out


def describe_windows(source: str = "eval", limit: int | None = None) -> str:
    """Where the windows come from, as the table's first line says it."""
    if source == "eval":
        what = "eval split" + (f", first {limit} clip(s)" if limit else "")
        return f"{what}, 65 frames every 40, PROTOCOL.md"
    subjects = source.partition(":")[2]
    what = "CMU takes" + (f" of subjects {subjects}" if subjects else "")
    what += f", first {limit} take(s)" if limit else ""
    return f"{what}, 65 frames every 40; not the protocol"


def markdown(results: dict, n_windows: int, transitions=TRANSITIONS, windows: str | None = None) -> str:
    names = list(results)
    lines = [f"Windows: {n_windows} ({windows or describe_windows()}).", ""]
    head = "| method | " + " | ".join(str(t) for t in transitions) + " |"
    sep = "|---|" + "---|" * len(transitions)
    for m in METRICS:
        lines += [f"**{m}**", "", head, sep]
        for name in names:
            cells = [f"{results[name][t][m]:.4f}" for t in transitions]
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        if m == "skate":
            cells = [f"{results[names[0]][t]['skate_gt']:.4f}" for t in transitions]
            lines.append("| ground truth | " + " | ".join(cells) + " |")
        if "interp" in results:
            for name in names:
                if name in ("interp", "zero"):
                    continue
                cells = [f"{results[name][t][m] / results['interp'][t][m]:.3f}" for t in transitions]
                lines.append(f"| {name} ÷ interp | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def run_bench(
    methods: list[str],
    limit: int | None,
    out_dir: Path,
    mirrored: bool = False,
    posture: float = 0.0,
    source: str = "eval",
) -> dict:
    # Every method loaded (its model folder checked) before the data: a damaged model was
    # refused only after the windows were read and the methods before it had run.
    loaded = {name: resolve(name) for name in methods}
    print("loading train statistics and the bench windows…", file=sys.stderr)
    mean, std = position_stats(load_split("train"))
    rots, roots = test_windows(limit, mirrored, posture, source)
    results = {}
    for name in methods:
        print(f"evaluating {name} on {len(rots)} windows…", file=sys.stderr)
        results[name] = evaluate(loaded[name], rots, roots, mean, std)
    payload = {
        "protocol": "PROTOCOL.md",
        "windows": int(len(rots)),
        "eval_clips_limit": limit if source == "eval" else None,
        "cmu_takes_limit": None if source == "eval" else limit,
        "mirrored": mirrored,
        "posture_offsets_deg": posture,
        "source": source,
        "results": {m: {str(t): v for t, v in r.items()} for m, r in results.items()},
    }
    md = markdown(results, len(rots), windows=describe_windows(source, limit))
    if posture:
        md = f"Posture offsets: up to {posture:g}° per joint (not the protocol).\n" + md
    if mirrored:
        md = "Mirrored: the left/right mirror image of every window (not the protocol).\n" + md
    write_outputs(out_dir, {"bench.json": json.dumps(payload, indent=1), "bench.md": md})
    return {"json": str(out_dir / "bench.json"), "markdown": md, "results": results}
