"""Tempo augmentation (pipeline/motion/augment.py): the same motion played faster or slower."""

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.motion.augment import tempo_factor, time_warp


def _spin(frames: int, deg_per_frame: float):
    angles = np.radians(deg_per_frame) * np.arange(frames)
    q = Rotation.from_rotvec(angles[:, None] * np.array([0.0, 1.0, 0.0])).as_quat()
    rot = np.repeat(q[None, :, None], 2, axis=2).astype(np.float32)  # (1, N, 2 joints, 4)
    root = np.stack([np.arange(frames) * 3.0, np.full(frames, 90.0), np.zeros(frames)], -1)[None]
    return rot, root.astype(np.float32)


def test_a_faster_tempo_plays_the_same_motion_in_fewer_frames():
    rot, root = _spin(41, 2.0)  # 80 degrees over 40 frames
    fast, fast_root = time_warp(rot, root, 21)  # twice as fast: 4 degrees a frame
    got = Rotation.from_quat(fast[0, :, 0].astype(np.float64)).as_rotvec()[:, 1]
    assert np.allclose(np.degrees(got), 4.0 * np.arange(21), atol=1e-3)
    assert np.allclose(fast_root[0, :, 0], 6.0 * np.arange(21), atol=1e-4)
    assert np.array_equal(fast_root[0, [0, -1]], root[0, [0, -1]])
    slow, _ = time_warp(rot, root, 81)  # half as fast: 1 degree a frame
    got = Rotation.from_quat(slow[0, :, 1].astype(np.float64)).as_rotvec()[:, 1]
    assert np.allclose(np.degrees(got), np.arange(81), atol=1e-3)
    assert fast.dtype == rot.dtype and np.allclose(np.linalg.norm(slow, axis=-1), 1.0, atol=1e-6)


def test_tempo_factors_stay_in_their_range_and_cover_both_directions():
    rng = np.random.default_rng(0)
    s = np.array([tempo_factor(rng, 0.4) for _ in range(2000)])
    assert s.min() >= 1 / 1.4 - 1e-12 and s.max() <= 1.4 + 1e-12
    assert (s < 0.8).any() and (s > 1.25).any()
    assert abs(np.median(np.log(s))) < 0.05  # log-uniform: as often slower as faster
