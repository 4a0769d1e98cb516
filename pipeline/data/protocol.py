"""PROTOCOL.md, step by step: windows, centring, facing alignment, statistics."""

from __future__ import annotations

import sys

import numpy as np
from tqdm import tqdm

from pipeline.atomic import replacing
from pipeline.data.cache import ClipSet, cache_dir
from pipeline.data.skeletons import bandai_skeleton
from pipeline.motion.fk import fk
from pipeline.motion.rotations import quat_apply, quat_mul
from pipeline.progress import interval

CONTEXT = 10
TRANSITIONS = (5, 15, 30, 45)
TEST_WINDOW, TEST_STRIDE = 65, 40
STATS_WINDOW, STATS_STRIDE = 50, 20
FACING_FRAME = 9


def window_starts(n_frames: int, length: int, stride: int) -> range:
    """A window starts at i while i + length < n_frames (so a clip of ``length`` frames gives none)."""
    return range(0, max(n_frames - length, 0), stride)


def windows_of(clips, length: int, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """All windows of an iterable of (rotations, roots) clips: (N, L, J, 4), (N, L, 3)."""
    rots, roots = [], []
    for r, p in clips:
        for i in window_starts(len(r), length, stride):
            rots.append(r[i : i + length])
            roots.append(p[i : i + length])
    return np.stack(rots), np.stack(roots)


def cut_windows(clips: ClipSet, length: int, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """All windows of all clips: rotations (N, L, J, 4), roots (N, L, 3)."""
    return windows_of((clips.clip(c) for c in range(len(clips))), length, stride)


def facing(positions: np.ndarray, skeleton=None) -> np.ndarray:
    """(UpperLeg_L − UpperLeg_R) × up, horizontal and unit, for positions (..., J, 3)."""
    skel = skeleton or bandai_skeleton()
    across = positions[..., skel.index("UpperLeg_L"), :] - positions[..., skel.index("UpperLeg_R"), :]
    f = np.cross(across, np.array([0.0, 1.0, 0.0]))
    f[..., 1] = 0.0
    return f / np.linalg.norm(f, axis=-1, keepdims=True)


def yaw_quat(angle: np.ndarray) -> np.ndarray:
    """Rotation by ``angle`` radians about +Y, xyzw."""
    half = 0.5 * np.asarray(angle, np.float64)
    z = np.zeros_like(half)
    return np.stack([z, np.sin(half), z, np.cos(half)], axis=-1)


def facing_turn(positions: np.ndarray, skeleton=None) -> np.ndarray:
    """(..., 4) yaw quaternions turning poses (..., J, 3) to face +X (see :func:`facing`)."""
    f = facing(positions, skeleton)
    # Rotating (x, 0, z) by +a about Y gives angle atan2(-z', x'): a = atan2(z, x) brings it to +X.
    return yaw_quat(np.arctan2(f[..., 2], f[..., 0]))


def normalize_windows(rots: np.ndarray, roots: np.ndarray, skeleton=None) -> tuple[np.ndarray, np.ndarray]:
    """Centre root X/Z on the window mean, then turn about Y to face +X at frame 9."""
    skel = skeleton or bandai_skeleton()
    roots = roots.astype(np.float64).copy()
    roots[..., [0, 2]] -= roots[..., [0, 2]].mean(axis=-2, keepdims=True)
    _, pos = fk(rots[:, FACING_FRAME], roots[:, FACING_FRAME], skel.parents, skel.offsets)
    q = facing_turn(pos, skel)[:, None]  # (N, 1, 4)
    new_roots = quat_apply(q, roots)
    new_rots = rots.astype(np.float64).copy()
    new_rots[..., 0, :] = quat_mul(q, new_rots[..., 0, :])
    return new_rots.astype(np.float32), new_roots.astype(np.float32)


def global_positions(rots: np.ndarray, roots: np.ndarray, skeleton=None) -> tuple[np.ndarray, np.ndarray]:
    skel = skeleton or bandai_skeleton()
    return fk(rots, roots, skel.parents, skel.offsets)


def position_stats(train: ClipSet, skeleton=None) -> tuple[np.ndarray, np.ndarray]:
    """x_mean, x_std (63,) of global positions over the normalised train statistics windows."""
    key = cache_dir() / f"stats-{len(train)}-{int(train.lengths.sum())}.npz"
    if key.exists():
        z = np.load(key)
        return z["mean"], z["std"]

    rots, roots = cut_windows(train, STATS_WINDOW, STATS_STRIDE)
    chunks = []
    for s in tqdm(range(0, len(rots), 1000), desc="train statistics", unit=" ×1000 windows", file=sys.stderr,
                  mininterval=interval()):  # fmt: skip
        r, p = normalize_windows(rots[s : s + 1000], roots[s : s + 1000], skeleton)
        _, pos = global_positions(r, p, skeleton)
        chunks.append(pos.reshape(-1, pos.shape[-2] * 3).astype(np.float64))
    flat = np.concatenate(chunks)
    mean, std = flat.mean(0), flat.std(0)
    # Written aside and renamed: two processes (test workers, farm workers) may ask at once.
    with replacing(key, suffix=".npz") as tmp:  # removed when interrupted
        np.savez(tmp, mean=mean, std=std)
    return mean, std
