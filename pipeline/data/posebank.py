"""A model's pose bank: a fixed sample of the poses it was trained on, for telling at fill time
how familiar a shot's keys are (:mod:`pipeline.infer.novelty`).

A pose is compared as its joints' positions relative to the root, turned to face +X (the
protocol's facing, :func:`pipeline.data.protocol.facing_turn`), in cm on the model skeleton:
where the character stands and which way it faces do not matter, its posture does. The bank
is ``POSES`` poses drawn at random (fixed seed) from every frame of the train split, stored as
float16 (a 0.01 cm step at these sizes) beside the model's networks, and named in model.json
(``pose_bank``).

``python -m pipeline.data.posebank OUT.npz [--poses 4096] [--seed 0]``
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from pipeline.arguments import Parser
from pipeline.data.cache import load_split
from pipeline.data.protocol import facing_turn
from pipeline.data.skeletons import bandai_skeleton
from pipeline.errors import TweenError
from pipeline.motion.fk import fk
from pipeline.motion.rotations import quat_apply

#: Poses in a bank (4,096 × 21 joints × 3 float16: 0.46 MB compressed). A random 4,096 of the
#: train split keep eval shots within 2.7 cm of the bank (20,000: 2.4 cm), CMU shots at 4.4 cm
#: or more (scripts/key_novelty.py; docs/trust.md).
POSES = 4096
VERSION = 1


def pose_features(rots: np.ndarray, roots: np.ndarray, skeleton=None) -> np.ndarray:
    """(M, J, 3) float32: each pose's joint positions relative to the root, facing +X, in the
    skeleton's units. ``rots`` (M, J, 4) local rotations, ``roots`` (M, 3)."""
    skel = skeleton or bandai_skeleton()
    _, pos = fk(np.asarray(rots, np.float64), np.asarray(roots, np.float64), skel.parents, skel.offsets)
    return posed_features(pos, skel)[0]


def posed_features(pos: np.ndarray, skeleton=None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`pose_features` of global joint positions (M, J, 3) already computed, and the
    yaw quaternions (M, 4) that turned each pose to face +X."""
    turn = facing_turn(pos, skeleton or bandai_skeleton())
    return quat_apply(turn[:, None], pos - pos[:, :1]).astype(np.float32), turn


def build(
    rots: np.ndarray, roots: np.ndarray, poses: int = POSES, seed: int = 0, skeleton=None
) -> np.ndarray:
    """(poses, J, 3) float16: ``poses`` frames of (F, J, 4) / (F, 3) drawn without replacement."""
    pick = np.sort(np.random.default_rng(seed).choice(len(rots), min(poses, len(rots)), replace=False))
    return pose_features(rots[pick], roots[pick], skeleton).astype(np.float16)


def save(path: str | Path, bank: np.ndarray, source: str) -> None:
    path = Path(path)
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, poses=bank, version=VERSION, source=source)
    tmp.replace(path)


def load(path: str | Path) -> np.ndarray:
    """(P, J, 3) float32 poses of a bank file; ValueError naming the file when it is not one."""
    try:
        with np.load(path) as d:
            poses = np.asarray(d["poses"], np.float32)
    except Exception as e:  # numpy's and zipfile's many ways of saying "not this file"
        why = " ".join(str(e).split()) or type(e).__name__
        raise ValueError(f"{path}: not a pose bank ({why})") from None
    if poses.ndim != 3 or poses.shape[-1] != 3 or not len(poses) or not np.isfinite(poses).all():
        raise ValueError(f"{path}: not a pose bank (poses of shape {poses.shape})")
    return poses


def _at_least_one(text: str) -> int:
    n = int(text)
    if n < 1:
        raise argparse.ArgumentTypeError(f"{n}: must be at least 1")
    return n


def main(argv=None) -> int:
    ap = Parser(prog="python -m pipeline.data.posebank", description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="the bank file to write (.npz)")
    ap.add_argument("--poses", type=_at_least_one, default=POSES)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    if not a.out.parent.is_dir():  # before the split is read
        raise TweenError(f"{a.out}: its folder {a.out.parent} is not a folder that exists")
    train = load_split("train")
    bank = build(train.rotations, train.roots, a.poses, a.seed)
    save(
        a.out, bank, f"bandai_namco train split, {len(bank)} of {len(train.rotations)} frames, seed {a.seed}"
    )
    print(f"{a.out}: {len(bank)} poses of {len(train.rotations)} train frames", file=sys.stderr)
    return 0


if __name__ == "__main__":
    from pipeline.command import run_main

    run_main(main)
