"""Layers that are no regular file where a command reads one: a FIFO in a shot's fill series
(USD's read of it blocked for ever: fill, approve, publish, review hung), a FIFO as the
tracker mapping, and a sublayer that is a link to nothing or a link loop (USD dropped it
without a word, even under --strict). Each is one line naming the file, at once."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from pipe_guard import within

from dailies import tracker
from dailies.tracker import TrackerError, read_mapping
from pipeline.errors import ShotError
from pipeline.fill.api import composition
from pipeline.fill.options import FillOptions
from pipeline.usd import write
from pipeline.usd.read import missing_assets

SHOT = Path(__file__).resolve().parents[2] / "examples" / "sh010_walk.usda"


@pytest.fixture
def shot(tmp_path) -> Path:
    s = tmp_path / "s.usda"
    s.write_text(SHOT.read_text())
    return s


def test_series_fifo_is_refused_naming_it(shot):
    fifo = shot.parent / "s.tween.v001.usda"
    os.mkfifo(fifo)
    with pytest.raises(ShotError) as e:
        within(lambda: write.check_series(str(shot), shot.parent, "s"), [fifo])
    assert str(fifo) in str(e.value) and "not a regular file" in str(e.value)
    assert "\n" not in str(e.value)
    with pytest.raises(ShotError, match="not a regular file"):
        within(lambda: write.find_job(shot.parent, "s", "job-1", str(shot)), [fifo])


def test_review_layer_fifo_is_refused_naming_it(shot):
    fifo = shot.parent / "s.review.v001.usda"
    os.mkfifo(fifo)
    with pytest.raises(ShotError, match="not a regular file") as e:
        within(lambda: write.check_review(fifo), [fifo])
    assert str(fifo) in str(e.value)


def test_series_folder_is_refused_and_a_dead_link_passes(shot):
    (shot.parent / "s.tween.v001.usda").mkdir()
    with pytest.raises(ShotError, match="a folder, not a fill layer"):
        write.check_series(str(shot), shot.parent, "s")
    (shot.parent / "s.tween.v001.usda").rmdir()
    (shot.parent / "s.tween.v001.usda").symlink_to(shot.parent / "gone.usda")
    write.check_series(str(shot), shot.parent, "s")  # nothing USD reads: as before, no record


def test_tracker_map_fifo_is_refused(tmp_path):
    fifo = tmp_path / "m.json"
    os.mkfifo(fifo)
    with pytest.raises(TrackerError) as e:
        within(lambda: read_mapping(fifo), [fifo])
    assert str(fifo) in str(e.value) and "not a regular file" in str(e.value)


def test_tracker_map_too_large_or_a_folder_is_refused(tmp_path):
    big = tmp_path / "big.json"
    big.write_bytes(b" " * (getattr(tracker, "MAPPING_LIMIT", 4 << 20) + 1))  # the old code had none
    with pytest.raises(TrackerError, match="too large"):
        read_mapping(big)
    with pytest.raises(TrackerError, match="a folder, not a tracker mapping"):
        read_mapping(tmp_path)
    ok = tmp_path / "ok.json"
    ok.write_text('{"s": {"sequence": "SQ01", "shot": "SH010"}}')
    assert read_mapping(ok) == {"s": {"sequence": "SQ01", "shot": "SH010"}}


def _with_sublayer(tmp_path: Path, sub: str) -> Path:
    x = tmp_path / "X.usda"
    x.write_text(SHOT.read_text().replace("\n(\n", f"\n(\n    subLayers = [@./{sub}@]\n", 1))
    assert "subLayers" in x.read_text()
    return x


@pytest.mark.parametrize("kind", ["dangling", "loop", "missing"])
def test_sublayer_link_to_nothing_is_a_missing_asset(tmp_path, kind):
    q = tmp_path / "q.usda"
    if kind == "dangling":
        q.symlink_to("/nonexistent/q.usda")
    elif kind == "loop":
        q.symlink_to(q.name)
    x = _with_sublayer(tmp_path, "q.usda")
    assert within(lambda: missing_assets(x)) == [str(q)]
    with pytest.raises(ShotError, match=r"missing sublayer.*q\.usda.*--strict"):
        composition(str(x), FillOptions(strict=True))
