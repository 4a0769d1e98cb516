"""Keys named with --keys on a shot sampled on every frame snap onto its samples with memory
that follows the samples, not samples x keys: 30,000 samples keyed every 10 made a 720 MB
table (the fill's peak, 1.6 GB) and 3 s per plan."""

from __future__ import annotations

import tracemalloc
from types import SimpleNamespace

import numpy as np

from pipeline.fill.plan import _keys_for
from pipeline.usd.read import TIME_EPS


def _char(samples):
    return SimpleNamespace(sample_times=np.asarray(samples, np.float64), key_override=None)


def test_named_keys_snap_onto_the_samples_near_them():
    samples = 1001.0 + np.arange(50) + np.r_[np.zeros(49), TIME_EPS / 4]  # the last just off a frame
    want = np.array([1050.0, 1001.0, 1010.5, 1020.0 + TIME_EPS / 2])  # unsorted, one between samples
    keys = _keys_for(None, _char(samples), want)
    assert keys.tolist() == [1001.0, 1010.5, 1020.0, samples[-1]]  # the authored times kept
    assert _keys_for(None, _char(samples), np.array([900.0])).tolist() == [900.0]


def test_named_keys_memory_follows_the_samples():
    samples = 1001.0 + np.arange(20_000)
    want = samples[::10].copy()
    tracemalloc.start()
    try:
        keys = _keys_for(None, _char(samples), want)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert np.array_equal(keys, want)
    assert peak < 16 * 2**20, f"snapping 2,000 keys onto 20,000 samples peaked at {peak / 2**20:.0f} MB"
