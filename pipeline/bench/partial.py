"""``tween bench --partial-keys``: the protocol's task with one partial key inside the gap.

Not part of PROTOCOL.md. The eval windows and metrics are the protocol's; besides the 10
context frames and the target, one frame halfway through the transition is keyed for some
channels only, as an animator blocks a passing position:
- ``root``: the root position only (where the character is, not its pose);
- ``legs``: hips and leg rotations, plus the root (the feet placed, the upper body free);
- ``upper``: spine, neck, head and arm rotations only (no root, no legs).
Metrics run over the transition frames, the partial key's frame included (its unkeyed
channels are predicted). Methods: interpolation per channel between its own keys, and each
model with the same mask (``OnnxInbetweener.fill_batch(joint_keys=...)``); a row without the
mid key at all shows what the partial key adds.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from pipeline.bench import metrics
from pipeline.bench.outputs import write_outputs
from pipeline.data.protocol import CONTEXT, global_positions
from pipeline.data.skeletons import bandai_skeleton
from pipeline.infer.features import interpolate

KINDS = ("root", "legs", "upper")
TRANSITIONS = (15, 30, 45)


def kind_columns(kind: str) -> np.ndarray:
    """Columns (joints, then the root at J) a partial key of ``kind`` keys."""
    names = bandai_skeleton().names
    J = len(names)
    legs = [i for i, n in enumerate(names) if "Leg" in n or "Foot" in n or "Toes" in n]
    if kind == "root":
        return np.array([J])
    if kind == "legs":
        return np.array([0, *legs, J])
    if kind == "upper":
        return np.array([i for i in range(1, J) if i not in legs])
    raise ValueError(f"unknown partial key kind {kind!r} ({', '.join(KINDS)})")


def task(T: int, kind: str | None):
    """(keys, joint key mask or None) for transition T in a protocol window."""
    J = len(bandai_skeleton())
    mid = CONTEXT + T // 2
    if kind is None:
        return np.r_[np.arange(CONTEXT), CONTEXT + T], None
    keys = np.r_[np.arange(CONTEXT), mid, CONTEXT + T]
    mask = np.ones((len(keys), J + 1), bool)
    mask[CONTEXT] = False
    mask[CONTEXT, kind_columns(kind)] = True
    return keys, mask


def fill_interp(rots, roots, keys, mask):
    q, r, _ = interpolate(rots, roots, keys, mask)
    return q, r


def evaluate_partial(fill, rots, roots, mean, std, batch: int = 64) -> dict:
    """{kind: {T: metrics}} for ``fill(rot, root, keys, mask) -> (rot, root)`` on windows."""
    out = {}
    for kind in (None, *KINDS):
        res = {}
        for T in TRANSITIONS:
            keys, mask = task(T, kind)
            n = CONTEXT + T + 1
            qs, rs = [], []
            for s in range(0, len(rots), batch):
                q, r = fill(rots[s : s + batch, :n], roots[s : s + batch, :n], keys, mask)
                qs.append(q)
                rs.append(r)
            q, r = np.concatenate(qs), np.concatenate(rs)
            sl = slice(CONTEXT, CONTEXT + T)
            gq_p, gp_p = global_positions(q[:, sl], r[:, sl])
            gq_t, gp_t = global_positions(rots[:, sl], roots[:, sl])
            res[T] = {
                "L2P": metrics.l2p(gp_p, gp_t, mean, std),
                "L2Q": metrics.l2q(gq_p, gq_t),
                "MPJPE": metrics.mpjpe(gp_p, gp_t),
            }
        out[kind or "no mid key"] = res
    return out


def markdown(results: dict) -> str:
    lines = []
    for metric in ("L2P", "MPJPE"):
        lines += [
            f"**{metric}** (transition {' / '.join(map(str, TRANSITIONS))})",
            "",
            "| method | " + " | ".join(["no mid key", *KINDS]) + " |",
            "|---|" + "---|" * (len(KINDS) + 1),
        ]
        for name, res in results.items():
            cells = [" / ".join(f"{res[k][T][metric]:.3f}" for T in TRANSITIONS) for k in res]
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def method_fill(name: str):
    """``fill(rot, root, keys, mask)`` for a method name: interp, model, or a model folder."""
    if name == "interp":
        return fill_interp
    from pipeline.infer.api import load_inbetweener

    return model_fill(load_inbetweener("default" if name == "model" else name))


def model_fill(inb):
    """``fill(rot, root, keys, mask)`` of an in-betweener, the mask as its ``joint_keys``."""
    return lambda rot, root, keys, mask: inb.fill_batch(rot, root, keys, None, mask)


def json_ready(results: dict) -> dict:
    """{method: {kind: {T: metrics}}} with the transition lengths as JSON keys."""
    return {m: {k: {str(t): v for t, v in r.items()} for k, r in d.items()} for m, d in results.items()}


def run_partial_bench(methods: list[str], rots, roots, mean, std, out_dir: Path) -> str:
    """Every method on the partial-key task; writes partial_keys.json and .md, returns the Markdown."""
    res = {}
    for m in methods:
        if m == "zero":
            continue
        print(f"partial keys: {m} on {len(rots)} windows…", file=sys.stderr)
        res[m] = evaluate_partial(method_fill(m), rots, roots, mean, std)
    md = markdown(res)
    text = json.dumps({"windows": len(rots), "results": json_ready(res)}, indent=1)
    write_outputs(out_dir, {"partial_keys.json": text, "partial_keys.md": md})
    return md
