"""GANimator's Table 1 metrics for a per-rig model trained on the Bandai dance clip.

    python experiments/rig_bench_dance.py MODEL_DIR [--samples 20] [--factor 2] [--clip BVH]
                                      [--frames A:B] [--no-contacts] [--out bench_results/rig_dance.json]

Synthesises ``--samples`` unconditional motions of ``--factor`` × the clip's length (the
official evaluation: 200 samples of 2×, seed 0) and reports coverage, global diversity (PNN)
and local diversity (pipeline/rig/diversity.py; the official evaluation's features and cost:
6D rows of the local rotations + the contact joints' labels, non-squared L2, ε = 2.0) against
the clip. Contact labels come from GANimator's velocity rule (0.018 m a frame) on the clip and
on each sample alike (the official code used the network's predicted labels for samples).
The table puts them next to the paper's Table 1 and two rows of our own as scale: the clip
itself (100 %, 0, 0) and a static pose. The paper's numbers are for a 24-joint Mixamo "Gangnam style"
clip of 371 frames; the Bandai dance is 1,901 frames on a 21-joint skeleton, so they are a
scale, not a target. Progress on stderr; the Markdown table on stdout; JSON to ``--out``.

Measured (2 shared CPU cores, 24 Nov 2026): a model trained with ``tween train-rig
dataset-1_dance-short_normal_001.bvh.gz --schedule reduced --iters 500 --seed 0 --threads 1``
(500 iterations per group instead of the reduced schedule's 1,500, 26.6 min wall at nice 19),
20 samples × 3,802 frames, 36 s for the script (≈0.4 s synthesis + 1.2 s metrics a sample):

| method | coverage ↑ | global diversity | local diversity |
|---|---|---|---|
| dance-r500 (20 samples × 3802 frames) | 14.9% | 2.45 | 2.30 |
| the clip itself | 100.0% | 0.00 | 0.00 |
| a static pose (the clip's middle frame) | 0.0% | 2.77 | 2.52 |
| *paper:* GANimator (Gangnam style) | 97.2% | 1.29 | 1.19 |

So that short run is far from the paper: its samples sit only a little nearer the clip than
a static pose. The tiny schedule (30 iterations) gives 0.1 % / 2.25 / 2.08.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

PAPER = [  # Table 1 of Li et al. 2022 (ganimator-notes.md §7)
    ("MotionTexture (2002)", 0.846, 1.03, 1.04),
    ("MotionTexture (Single)", 1.0, 0.21, 0.33),
    ("acRNN (2018)", 0.116, 5.63, 6.69),
    ("GANimator (paper, Gangnam style)", 0.972, 1.29, 1.19),
]


def _dance_clip() -> Path:
    from pipeline.data.split import shared_data_dir

    found = sorted((shared_data_dir() / "bandai_namco").rglob("dataset-1_dance-short_normal_001.bvh.gz"))
    if not found:
        sys.exit("rig_bench_dance: dataset-1_dance-short_normal_001.bvh.gz not found under the shared data")
    return found[0]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("model", type=Path)
    ap.add_argument("--samples", type=int, default=20, help="samples to synthesise (the paper: 200)")
    ap.add_argument("--factor", type=float, default=2.0, help="sample length ÷ clip length")
    ap.add_argument("--seed", type=int, default=0, help="seed of the first sample")
    ap.add_argument("--clip", type=Path, default=None, help="the training clip (default: the Bandai dance)")
    ap.add_argument("--frames", default=None, help="START:STOP of the clip the model was trained on")
    ap.add_argument("--no-contacts", action="store_true", help="rotation features only")
    ap.add_argument("--out", type=Path, default=Path("bench_results") / "rig_dance.json")
    a = ap.parse_args(argv)

    from pipeline.motion.clip import resample
    from pipeline.rig import diversity
    from pipeline.rig.infer import RigInbetweener
    from pipeline.rig.source import load_rig_source, parse_frames

    inb = RigInbetweener(a.model)
    clip_path = a.clip or _dance_clip()
    clip = load_rig_source(clip_path, frames=parse_frames(a.frames))
    if abs(clip.fps - inb.fps) > 1e-6:
        clip = resample(clip, inb.fps)
    if clip.skeleton.names != inb.skeleton.names:
        sys.exit(f"rig_bench_dance: {a.model} was trained on another skeleton than {clip_path}")
    contacts = (
        [] if a.no_contacts else [j for j in inb.meta.get("contact_joints", []) if j in clip.skeleton.names]
    )

    def feats(motion):
        lab = diversity.contact_labels(motion, contacts) if contacts else None
        return diversity.features(motion.rotations, lab)

    src = feats(clip)
    n = int(round(a.factor * len(clip)))
    print(f"{clip_path.name}: {len(clip)} frames at {clip.fps:g} fps, {len(clip.skeleton)} joints, "
          f"contacts {contacts or 'none'}; {a.samples} samples of {n} frames", file=sys.stderr)  # fmt: skip
    per = []
    t0 = time.perf_counter()
    for i in range(a.samples):
        t1 = time.perf_counter()
        sample = inb.synthesize(n, seed=a.seed + i)
        t_syn = time.perf_counter() - t1
        q = feats(sample)
        r = {
            "seed": a.seed + i,
            "coverage": diversity.coverage(q, src),
            "global_diversity": diversity.global_diversity(q, src).value,
            "local_diversity": diversity.local_diversity(q, src),
            "synth_s": round(t_syn, 3),
            "metrics_s": round(time.perf_counter() - t1 - t_syn, 3),
        }
        per.append(r)
        print(f"  sample {i + 1}/{a.samples}: cov {r['coverage']:.3f} glob {r['global_diversity']:.3f} "
              f"loc {r['local_diversity']:.3f} ({r['synth_s']:.2f} s + {r['metrics_s']:.2f} s)", file=sys.stderr)  # fmt: skip
    mean = {
        k: float(np.mean([r[k] for r in per])) for k in ("coverage", "global_diversity", "local_diversity")
    }
    # Reference rows of our own: the clip itself (coverage 1, diversity 0) and a static pose.
    still = clip.slice(len(clip) // 2, len(clip) // 2 + 1)
    still_q = feats(
        type(clip)(
            clip.skeleton, np.repeat(still.rotations, n, 0), np.repeat(still.root_positions, n, 0), clip.fps
        )
    )
    static = {
        "coverage": diversity.coverage(still_q, src),
        "global_diversity": diversity.global_diversity(still_q, src).value,
        "local_diversity": diversity.local_diversity(still_q, src),
    }
    rows = [(f"{inb.name} ({a.samples} samples × {n} frames)", mean["coverage"], mean["global_diversity"],
             mean["local_diversity"]),
            ("the clip itself", 1.0, 0.0, 0.0),
            ("a static pose (the clip's middle frame)", static["coverage"], static["global_diversity"],
             static["local_diversity"])]  # fmt: skip
    md = ["| method | coverage ↑ | global diversity | local diversity |", "|---|---|---|---|"]
    md += [f"| {m} | {c * 100:.1f}% | {g:.2f} | {ld:.2f} |" for m, c, g, ld in rows]
    md += [f"| *paper:* {m} | {c * 100:.1f}% | {g:.2f} | {ld:.2f} |" for m, c, g, ld in PAPER]
    text = "\n".join(md)
    print(text)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({
        "model": inb.name, "model_hash": inb.model_hash, "clip": str(clip_path), "clip_frames": len(clip),
        "fps": clip.fps, "samples": a.samples, "sample_frames": n, "contacts": contacts, "mean": mean,
        "static_pose": static, "per_sample": per, "paper": PAPER, "seconds": round(time.perf_counter() - t0, 1),
        "markdown": text,
    }, indent=1))  # fmt: skip
    print(f"written: {a.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
