"""Pipes (FIFOs) in a shot folder, named like its layers: the dailies page and the API never
open one (USD's read of a pipe waits for a writer for ever, holding the request and every
request after it); they treat it as they treat a layer they cannot read."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from dailies_fixtures import client_for
from pipe_guard import within

STEM = "sh010"
KEY = f"0/seq01/{STEM}"


def _fill(path: Path) -> None:
    """A fill layer's metadata only (what the list reads)."""
    path.write_text(
        "#usda 1.0\n(\n    customLayerData = {\n        dictionary tween = {\n"
        '            string createdAt = "2024-01-01T00:00:00+00:00"\n'
        '            string model = "interp"\n'
        f'            string review = "{STEM}.review.v001.usda"\n'
        "            int takes = 2\n        }\n    }\n)\n"
    )


def _shot_folder(root: Path) -> Path:
    """One shot filled once: the animator's shot, its fill layer v001 and review layer v001."""
    folder = root / "seq01"
    folder.mkdir(parents=True)
    (folder / f"{STEM}.usda").write_text("#usda 1.0\n(\n    timeCodesPerSecond = 30\n)\n")
    _fill(folder / f"{STEM}.tween.v001.usda")
    (folder / f"{STEM}.review.v001.usda").write_text(
        f"#usda 1.0\n(\n    subLayers = [\n        @./{STEM}.tween.v001.usda@,\n        @./{STEM}.usda@\n    ]\n)\n"
    )
    return folder


def _pages(root: Path) -> dict:
    """The list (API and page) and the shot (API and page), each answered."""
    c = client_for([root])
    out = {url: c.get(url) for url in ("/api/shots", "/", f"/api/shots/{KEY}", f"/shot/{KEY}")}
    assert all(r.status_code == 200 for r in out.values()), {u: r.text[:200] for u, r in out.items()}
    return out


@pytest.mark.parametrize(
    "name",
    [
        f"{STEM}.review.v002.usda",  # the review layer of a fill not there: before, it held the list
        f"{STEM}.review.v001.usda",  # the latest fill's review layer
        f"{STEM}.tween.v002.usda",  # a later fill version
        f"{STEM}.usda",  # the animator's shot, the review layer's last sublayer
    ],
)
def test_a_pipe_named_like_a_layer_of_the_shot_holds_no_request(tmp_path, name):
    folder = _shot_folder(tmp_path)
    fifo = folder / name
    fifo.unlink(missing_ok=True)
    os.mkfifo(fifo)
    pages = within(lambda: _pages(tmp_path), [fifo])
    (row,) = pages["/api/shots"].json()
    shot = pages[f"/api/shots/{KEY}"].json()
    if name == f"{STEM}.review.v002.usda":
        # As a review layer USD cannot read: the fill it stacks is named as a .usda one.
        assert row["status"] == "latest fill missing" and row["missing"] == f"{STEM}.tween.v002.usda"
        assert (
            row["version"] == 2 and f"its fill layer {STEM}.tween.v002.usda is not there" in pages["/"].text
        )
    else:  # the pipe is no layer of the shot: the fill v001 is its latest
        assert (row["status"], row["version"], row["model"]) == ("pending", 1, "interp")
    assert shot["version"] == 1 and shot["layer"] == f"{STEM}.tween.v001.usda"
