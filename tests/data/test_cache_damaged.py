"""A damaged clip cache ($TWEEN_CACHE/clips-*.npz) is read again from the clips and rewritten.
Before: a cut file was an internal error (BadZipFile), and a wrong lengths array an IndexError
once training had started."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.data.cache import load_split


def _cut(path):
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _junk(path):
    path.write_bytes(b"PK\x03\x04 not a zip")


def _lengths(path):
    with np.load(path) as z:
        arrays = dict(z)
    arrays["lengths"] = arrays["lengths"] * 3  # past the frames the file holds
    np.savez(path, **arrays)


def _starts(path):
    with np.load(path) as z:
        arrays = dict(z)
    arrays["starts"] = arrays["starts"][:0]
    np.savez(path, **arrays)


@pytest.mark.parametrize("damage", [_cut, _junk, _lengths, _starts], ids=lambda f: f.__name__[1:])
def test_a_damaged_cache_is_rebuilt(tmp_path, monkeypatch, capsys, damage):
    monkeypatch.setenv("TWEEN_CACHE", str(tmp_path / "cache"))
    whole = load_split("train", limit=2)
    (path,) = (tmp_path / "cache").rglob("clips-*.npz")
    damage(path)
    capsys.readouterr()
    again = load_split("train", limit=2)
    err = capsys.readouterr().err
    assert f"tween: warning: {path}: damaged clip cache" in err and err.count("\n") == 1, err
    assert again.names == whole.names and again.fps == whole.fps
    for a in ("starts", "lengths", "rotations", "roots"):
        assert np.array_equal(getattr(again, a), getattr(whole, a)), a
    capsys.readouterr()
    load_split("train", limit=2)
    assert capsys.readouterr().err == ""  # written again whole: read from the cache
