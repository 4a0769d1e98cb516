"""A cache write interrupted (Ctrl-C, SIGTERM: KeyboardInterrupt) leaves nothing in the cache:
the temporaries of the clip sets and the train statistics were named after the process and
stayed, ~120 MB each for the train split, never read or removed by a later run."""

import os

import numpy as np
import pytest

from pipeline.data.cache import load_split
from pipeline.data.protocol import position_stats


def test_an_interrupted_cache_write_leaves_no_temporary(tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    monkeypatch.setenv("TWEEN_CACHE", str(cache))
    real_savez = np.savez

    def interrupted(file, **arrays):
        real_savez(file, **arrays)  # written whole, then interrupted before the rename
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez", interrupted)
    with pytest.raises(KeyboardInterrupt):
        load_split("train", limit=1)
    assert os.listdir(cache) == []
    monkeypatch.setattr(np, "savez", real_savez)
    clips = load_split("train", limit=1)
    made = os.listdir(cache)
    monkeypatch.setattr(np, "savez", interrupted)
    with pytest.raises(KeyboardInterrupt):
        position_stats(clips)
    assert os.listdir(cache) == made
