"""A long review's memory follows its frames, not frames x keys: which frames are keys
(``Shot.is_key``, read three times by every review) on a 20,000-frame shot keyed every 10
frames once made a 320 MB table; the 30,000-frame review peaked at 1.8 GB for it."""

from __future__ import annotations

import tracemalloc

import numpy as np

from render.scene import Shot


def _shot(times, keys) -> Shot:
    times = np.asarray(times, np.float64)
    return Shot("sh", "sh.usda", 24.0, times, np.round(times).astype(int), np.asarray(keys, np.float64),
                {}, None, [], None)  # fmt: skip


def test_is_key_matches_every_frame_against_every_key():
    rng = np.random.default_rng(3)
    times = np.sort(rng.uniform(0, 200, 400))
    keys = np.r_[times[rng.choice(400, 30, replace=False)] + rng.uniform(-0.02, 0.02, 30), -5, 500]
    shot = _shot(times, rng.permutation(keys))  # unsorted keys, some off any frame
    for tol in (None, 0.01, 0.3):
        step = float(np.median(np.diff(times)))
        t = 0.01 * step if tol is None else tol
        want = np.abs(times[:, None] - keys[None, :]).min(1) <= t
        assert np.array_equal(shot.is_key(tol), want)
    assert not _shot(times, []).is_key().any()
    assert _shot([1001.0], [1001.0]).is_key().tolist() == [True]


def test_is_key_memory_follows_the_frames():
    times = 1001.0 + np.arange(20_000)
    shot = _shot(times, times[::10])
    tracemalloc.start()
    try:
        is_key = shot.is_key()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert is_key.sum() == 2_000 and is_key[::10].all()
    assert peak < 8 * 2**20, f"is_key peaked at {peak / 2**20:.0f} MB for 20,000 frames"
