"""What a motion DNA does to a fill, on the protocol's eval windows.

python experiments/dna_effect.py MODEL_DIR [--poses R] [--every K] [--out FILE.json]

For each window and transition length (30 and 45 frames, where there is room for a pose to
show), the generator fills the gap with no DNA and with R representative poses
(``pipeline.infer.dna_poses.representative_frames``) taken from:
- ``gap``: the true in-between frames (what training showed it; an upper bound);
- ``same clip``: the rest of the same take, outside the window (the same motion: the use
  the paper intends, "representative frames from the same motion class");
- ``other clip``: another eval take (a different motion: how far a DNA can pull).
Reported: L2P (protocol units) and the DNA distance of eq. 11 — for each DNA pose, the mean
per-joint distance (cm, root-relative, facing +X) to its nearest in-between frame — for the
fill with that DNA and for the fill without one. A model that uses its DNA brings that
distance down; one that ignores it leaves both columns equal.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from pipeline.bench import metrics
from pipeline.data.cache import load_split
from pipeline.data.protocol import (
    CONTEXT,
    TEST_STRIDE,
    TEST_WINDOW,
    global_positions,
    normalize_windows,
    position_stats,
)
from pipeline.data.skeletons import bandai_skeleton
from pipeline.infer.dna_poses import POSE_SCALE, dna_poses, representative_frames
from pipeline.infer.generator_onnx import OnnxInbetweener, take_latent

SOURCES = ("gap", "same clip", "other clip")


def windows(clips) -> list[tuple[int, int]]:
    """(clip index, start) of the protocol's windows."""
    out = []
    for c in range(len(clips)):
        r, _ = clips.clip(c)
        for s in range(0, max(len(r) - TEST_WINDOW, 0), TEST_STRIDE):
            out.append((c, s))
    return out


def pick_dna(clips, c: int, s: int, T: int, source: str, R: int) -> np.ndarray:
    rot, _ = clips.clip(c)
    if source == "gap":
        frames = np.arange(s + CONTEXT, s + CONTEXT + T)
    elif source == "same clip":
        frames = np.r_[np.arange(0, max(s - 15, 0)), np.arange(s + TEST_WINDOW + 15, len(rot))]
        if len(frames) < R:
            return None
    else:
        rot, _ = clips.clip((c + len(clips) // 2) % len(clips))
        frames = np.arange(len(rot))
    idx = np.resize(representative_frames(rot, R, spacing=5, frames=frames), R)
    return rot[idx]


def window_l2p(q, r, truth, mean, std) -> np.ndarray:
    """(B,) the protocol's L2P of each window's in-between frames."""
    _, p = global_positions(q[:, CONTEXT:-1], r[:, CONTEXT:-1])
    return np.array([metrics.l2p(p[j : j + 1], truth[j : j + 1], mean, std) for j in range(len(p))])


def dna_distance(rot, root, dna, skel) -> np.ndarray:
    """(B,) eq. 11 in cm: each DNA pose to its nearest frame of (B, T, J, 4) rot, mean per joint."""
    out = []
    for b in range(len(rot)):
        frames = dna_poses(rot[b], root[b], skel).T.reshape(len(rot[b]), -1, 3)
        want = dna_poses(dna[b], np.zeros((len(dna[b]), 3)), skel).T.reshape(len(dna[b]), -1, 3)
        d = np.linalg.norm(frames[None] - want[:, None], axis=-1).mean(-1) * POSE_SCALE
        out.append(d.min(axis=1).mean())
    return np.array(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model")
    ap.add_argument("--poses", type=int, default=3)
    ap.add_argument("--every", type=int, default=1, help="Every k-th window only (quick checks).")
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    skel = bandai_skeleton()
    inb = OnnxInbetweener(a.model)
    clips = load_split("eval")
    mean, std = position_stats(load_split("train"))
    wins = windows(clips)[:: a.every]
    report = {}
    for T in (30, 45):
        L = CONTEXT + T + 1
        keys = np.r_[np.arange(CONTEXT), L - 1]
        rows = {src: {"L2P": [], "dist": [], "dist_none": []} for src in SOURCES}
        rows["none"] = {"L2P": []}
        for i in range(0, len(wins), 64):
            chunk = wins[i : i + 64]
            rot = np.stack([clips.clip(c)[0][s : s + TEST_WINDOW] for c, s in chunk])
            root = np.stack([clips.clip(c)[1][s : s + TEST_WINDOW] for c, s in chunk])
            rot, root = normalize_windows(rot, root)  # as the protocol: centred, facing +X
            rot, root = rot[:, :L], root[:, :L]
            noise = np.repeat(take_latent(0)[None], len(chunk), 0)
            _, truth = global_positions(rot[:, CONTEXT:-1], root[:, CONTEXT:-1])

            q0, r0 = inb.fill_batch(rot, root, keys, noise)
            rows["none"]["L2P"].append(window_l2p(q0, r0, truth, mean, std))
            for src in SOURCES:
                dna = [pick_dna(clips, c, s, T, src, a.poses) for c, s in chunk]
                ok = np.array([d is not None for d in dna])
                if not ok.any():
                    continue
                dna = np.stack([d for d in dna if d is not None])
                q, r = inb.fill_batch(rot[ok], root[ok], keys, noise[ok], dna=dna)
                rows[src]["L2P"].append(window_l2p(q, r, truth[ok], mean, std))
                rows[src]["dist"].append(dna_distance(q[:, CONTEXT:-1], r[:, CONTEXT:-1], dna, skel))
                rows[src]["dist_none"].append(
                    dna_distance(q0[ok][:, CONTEXT:-1], r0[ok][:, CONTEXT:-1], dna, skel)
                )
                rows[src].setdefault("L2P_none", []).append(rows["none"]["L2P"][-1][ok])
        report[T] = {}
        print(f"\nT = {T}: {len(wins)} windows, {a.poses} DNA poses")
        print(
            "| DNA from | windows | L2P without DNA | L2P with DNA | DNA distance without (cm) | with (cm) |"
        )
        print("|---|---|---|---|---|---|")
        for src in SOURCES:
            v = {k: np.concatenate(x) for k, x in rows[src].items() if x}
            report[T][src] = {k: float(x.mean()) for k, x in v.items()} | {"windows": len(v["L2P"])}
            print(f"| {src} | {len(v['L2P'])} | {v['L2P_none'].mean():.3f} | {v['L2P'].mean():.3f} | "
                  f"{v['dist_none'].mean():.2f} | {v['dist'].mean():.2f} |", flush=True)  # fmt: skip
    if a.out:
        with open(a.out, "w") as f:
            json.dump(report, f, indent=1)


if __name__ == "__main__":
    main()
