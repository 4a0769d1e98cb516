"""Shot time codes onto the model's frames (pipeline.fill.solve.model_time): every key the
in-betweener is given lands on its model frame, whatever the shot's rate, so that a 24 fps
shot's fill is not moved up to half a model frame off its keys."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.fill.solve import model_frames, model_time


@settings(max_examples=200, deadline=None)
@given(
    tcps=st.sampled_from([24.0, 25.0, 30.0, 48.0, 60.0, 23.976, 29.97]),
    gaps=st.lists(st.integers(1, 40), min_size=1, max_size=12),
    start=st.integers(-50, 50),
)
def test_each_key_lands_on_its_model_frame_and_time_runs_forward(tcps, gaps, start):
    keys = start + np.r_[0, np.cumsum(gaps)].astype(np.float64)
    m, keep = model_frames(keys, tcps, 30.0)
    assert np.allclose(model_time(keys[keep], keys, tcps, 30.0), m[keep], atol=1e-9)
    times = np.linspace(keys[0], keys[-1], 997)
    u = model_time(times, keys, tcps, 30.0)
    assert (np.diff(u) >= -1e-12).all()
    # Never further from the rate's own mapping than the half model frame the rounding moves a key.
    assert np.abs(u - (times - keys[0]) / tcps * 30.0).max() <= 0.5 + 1e-9


def test_keys_on_model_frames_keep_the_rates_mapping_bit_for_bit():
    times = np.arange(0.0, 21.0)
    on_grid = np.array([0.0, 10.0, 20.0])
    assert np.array_equal(model_time(times, on_grid, 30.0, 30.0), times / 30.0 * 30.0)
    assert np.array_equal(model_time(times, on_grid, 60.0, 30.0), times / 60.0 * 30.0)


def test_a_24_fps_shot_keyed_every_10_is_mapped_gap_by_gap():
    keys = np.array([0.0, 10.0, 20.0, 30.0])  # each key 12.5 model frames from the last
    m, _ = model_frames(keys, 24.0, 30.0)
    assert list(m) == [0, 12, 25, 38]  # filled at the nearer frame (rounded half to even)
    assert np.allclose(model_time(keys, keys, 24.0, 30.0), m)
    assert np.isclose(model_time(np.array([5.0]), keys, 24.0, 30.0)[0], 6.0)  # halfway between 0 and 12
    assert np.isclose(model_time(np.array([25.0]), keys, 24.0, 30.0)[0], 31.5)  # halfway between 25 and 38
