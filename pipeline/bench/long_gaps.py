"""``tween bench --long-gaps``: keys 2, 5 and 10 s apart on long takes.

On the eval clips of at least 10 s and on the long CMU takes (mapped onto the model
skeleton through the product's own USD retargeting), keys are placed every gap; each
method fills the rest. Per gap: the mean joint speed against the ground truth's (the motion
must keep moving: 50–150 %), the largest bone-length change, and the MPJPE.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from pipeline.bench.outputs import write_outputs
from pipeline.data.skeletons import bandai_skeleton
from pipeline.data.split import list_clips, shared_data_dir
from pipeline.motion.bvh import read_bvh
from pipeline.motion.clip import Motion
from pipeline.motion.fk import fk

GAPS_S = (2, 5, 10)
MIN_SECONDS = 10.0


def cmu_on_model_skeleton(path: Path, fps: float = 30.0) -> Motion:
    """A CMU/iClone take retargeted onto the model skeleton via a converted USD shot."""
    from pipeline.usd.take import model_take

    return model_take(path, fps)


def long_takes(limit: int | None = None) -> list[tuple[str, Motion]]:
    takes = []
    for f in list_clips("eval"):
        m = read_bvh(f)
        if m.duration >= MIN_SECONDS:
            takes.append(("bandai-eval", m.continuous()))
    cmu = sorted((shared_data_dir() / "cmu_iclone").glob("*.bvh.gz"))
    for f in cmu[: limit or None]:
        m = cmu_on_model_skeleton(f)
        if m.duration >= MIN_SECONDS:
            takes.append(("cmu", m))
    return takes


def _speed(pos: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(pos, axis=0), axis=-1).mean())


def evaluate_long_gaps(inbetweener, takes, gaps_s=GAPS_S) -> dict:
    skel = bandai_skeleton()
    bones = np.arange(1, len(skel))
    rest = np.linalg.norm(skel.offsets[bones], axis=-1)
    out: dict = {}
    for source in sorted({s for s, _ in takes}):
        for g_s in gaps_s:
            ratios, bone_err, mpjpe, n = [], 0.0, [], 0
            for s, m in takes:
                if s != source:
                    continue
                g = int(round(g_s * m.fps))
                n_frames = (len(m) - 1) // g * g + 1
                if n_frames < g + 1:
                    continue
                clip = m.slice(0, n_frames)
                keys = np.arange(0, n_frames, g)
                filled = inbetweener.fill(clip, keys)
                _, p_pred = fk(filled.rotations, filled.root_positions, skel.parents, skel.offsets)
                _, p_true = clip.fk()
                d = np.linalg.norm(p_pred[:, bones] - p_pred[:, skel.parents[bones]], axis=-1)
                bone_err = max(bone_err, float(np.abs(d - rest).max()))
                for a, b in zip(keys[:-1], keys[1:], strict=True):
                    true_speed = _speed(p_true[a : b + 1])
                    if true_speed < 1e-3:  # a still take: "keeps moving" is undefined
                        continue
                    ratios.append(_speed(p_pred[a : b + 1]) / true_speed)
                    mpjpe.append(float(np.linalg.norm(p_pred[a + 1 : b] - p_true[a + 1 : b], axis=-1).mean()))
                    n += 1
            r = np.array(ratios)
            out[f"{source}/{g_s}s"] = {
                "gaps": n,
                "speed_ratio_mean": float(r.mean()) if n else None,
                "speed_ratio_in_50_150": float(((r >= 0.5) & (r <= 1.5)).mean()) if n else None,
                "speed_ratio_p10_p90": [float(np.percentile(r, 10)), float(np.percentile(r, 90))]
                if n
                else None,
                "max_bone_length_change_cm": bone_err,
                "mpjpe_cm": float(np.mean(mpjpe)) if n else None,
            }
            print(f"  {source} {g_s}s: {n} gaps", file=sys.stderr)
    return out


def markdown(results: dict) -> str:
    lines = [
        "| method | take set / gap | gaps | speed ratio (mean) | in 50–150 % | p10–p90 | max bone Δ (cm) | MPJPE (cm) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, res in results.items():
        for k, v in res.items():
            if not v["gaps"]:
                continue
            lines.append(
                f"| {name} | {k} | {v['gaps']} | {v['speed_ratio_mean']:.2f} | {100 * v['speed_ratio_in_50_150']:.0f} % "
                f"| {v['speed_ratio_p10_p90'][0]:.2f}–{v['speed_ratio_p10_p90'][1]:.2f} "
                f"| {v['max_bone_length_change_cm']:.1e} | {v['mpjpe_cm']:.1f} |"
            )
    return "\n".join(lines)


def run_long_gap_bench(methods: list[str], limit: int | None, out_dir: Path) -> str:
    """Every method (zero is skipped: it does not move) on the long takes; writes
    long_gaps.json and .md under ``out_dir``, returns the Markdown."""
    from pipeline.infer.api import load_inbetweener

    takes = long_takes(limit)
    res = {}
    for m in methods:
        name = {"model": "default", "zero": None}.get(m, m)
        if name is None:
            continue
        print(f"long gaps: {m} on {len(takes)} takes…", file=sys.stderr)
        res[m] = evaluate_long_gaps(load_inbetweener(name), takes)
    md = markdown(res)
    write_outputs(out_dir, {"long_gaps.json": json.dumps(res, indent=1), "long_gaps.md": md})
    return md
