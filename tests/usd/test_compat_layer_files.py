"""A fill layer of the version series, or a ``--review-layer``, that is no regular file is
said as what it is (a link loop, a folder, a pipe): one line naming it, exit 2, nothing
written. A link loop read as "permission denied", a folder or a pipe as "no such file"."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from usd_fixtures import tween

SHOT = Path(__file__).resolve().parents[2] / "examples" / "sh010_walk.usda"


def _one_error(rc: int, err: str, *words: str) -> None:
    assert rc == 2, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("tween: error: "), err
    for w in words:
        assert w in lines[0], (w, err)


@pytest.fixture
def shot(tmp_path):
    out = tmp_path / "sh010.usda"
    out.write_bytes(SHOT.read_bytes())
    return out


@pytest.mark.parametrize("loop", ["itself", "a pair"])
def test_a_fill_layer_that_is_a_link_loop_is_said_as_one(shot, loop, monkeypatch, capsys):
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--model", "interp")
    assert rc == 0, err
    bad = shot.parent / "sh010.tween.v002.usda"
    if loop == "itself":
        bad.symlink_to(bad.name)
    else:
        (shot.parent / "other.usda").symlink_to(bad.name)
        bad.symlink_to("other.usda")
    before = sorted(p.name for p in shot.parent.iterdir())
    for args in (
        ("fill-local", shot, "--model", "interp"),
        ("approve", shot, "--take", "0"),
        ("publish", shot),
    ):
        rc, err = tween(monkeypatch, capsys, *args)
        _one_error(rc, err, str(bad), "a link loop", "not a fill layer")
        assert "permission denied" not in err
    assert sorted(p.name for p in shot.parent.iterdir()) == before  # no new version


def test_a_review_layer_of_the_series_that_is_a_link_loop_is_said_as_one(shot, monkeypatch, capsys):
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--model", "interp")
    assert rc == 0, err
    review = shot.parent / "sh010.review.v001.usda"
    review.unlink()
    review.symlink_to(review.name)
    rc, err = tween(monkeypatch, capsys, "review", shot)
    _one_error(rc, err, str(review), "a link loop", "not a review layer")


@pytest.mark.parametrize("kind", ["folder", "pipe", "link loop"])
def test_a_review_layer_option_that_is_no_file_is_said_as_what_it_is(shot, kind, monkeypatch, capsys):
    review = shot.parent / "root.usda"
    if kind == "folder":
        review.mkdir()
        said = "a folder, not a review layer"
    elif kind == "pipe":
        os.mkfifo(review)
        said = "not a regular file (a pipe, socket or device), not a review layer"
    else:
        review.symlink_to(review.name)
        said = "a link loop"
    before = sorted(p.name for p in shot.parent.iterdir())
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--model", "interp", "--review-layer", review)
    _one_error(rc, err, "--review-layer", str(review), said)
    assert "no such file" not in err
    assert sorted(p.name for p in shot.parent.iterdir()) == before
