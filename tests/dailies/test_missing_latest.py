"""A shot whose latest fill layer was deleted by hand, its review layer left: the list showed
the fill before it as the latest (pending, with its model and takes), which `tween review`,
approve and publish refuse to take for the latest (pipeline.usd.write.check_latest_there).
It is shown as that instead, naming the layer; every other shot's row stays as it was."""

from pathlib import Path

from dailies_fixtures import client_for

from dailies import shots

KEYS = ["key", "stem", "folder", "version", "versions", "status", "decision", "published", "model", "takes",
        "created", "mtime"]  # fmt: skip


def _fill(path: Path) -> None:
    """A fill layer's metadata only (what the list reads)."""
    path.write_text(
        "#usda 1.0\n(\n    customLayerData = {\n        dictionary tween = {\n"
        '            string createdAt = "2024-01-01T00:00:00+00:00"\n'
        '            string model = "interp"\n            int takes = 2\n        }\n    }\n)\n'
    )


def _review(folder: Path, stem: str, n: int, fill: str | None = None) -> None:
    """The review layer of version ``n``, stacking its fill layer (``fill``: its file name)."""
    fill = fill or f"{stem}.tween.v{n:03d}.usda"
    (folder / f"{stem}.review.v{n:03d}.usda").write_text(
        f"#usda 1.0\n(\n    subLayers = [\n        @./{fill}@,\n        @./{stem}.usda@\n    ]\n)\n"
    )


def test_a_latest_fill_deleted_by_hand_is_shown_as_missing(tmp_path):
    folder = tmp_path / "seq01"
    folder.mkdir()
    for stem in ("sh010", "sh020", "sh030", "sh040"):
        _fill(folder / f"{stem}.tween.v001.usda")
        _review(folder, stem, 1)
    _review(folder, "sh010", 2)  # sh010.tween.v002.usda deleted by hand
    _review(folder, "sh040", 2, "sh040.tween.v002.usdc")  # a .usdc fill, deleted
    _review(folder, "sh020", 2)  # v002 being written: its review first, then its temp is linked
    (folder / ".sh020.tween.v002.4242@host.tmp.usda").write_text("")
    rows = {r["key"]: r for r in shots.listing([tmp_path])}
    for key, name in (("0/seq01/sh010", "sh010.tween.v002.usda"), ("0/seq01/sh040", "sh040.tween.v002.usdc")):
        assert rows[key]["status"] == "latest fill missing" and rows[key]["missing"] == name, rows[key]
        assert rows[key]["version"] == 2 and rows[key]["model"] == "" and rows[key]["decision"] is None
    for key in ("0/seq01/sh020", "0/seq01/sh030"):  # as before
        assert list(rows[key]) == KEYS and (rows[key]["status"], rows[key]["version"]) == ("pending", 1)

    page = client_for([tmp_path]).get("/").text
    waiting, missing = page.split('id="pending"')[1].split("</table>")[0], page.split('id="missing"')[1]
    assert "sh020" in waiting and "sh030" in waiting and "sh010" not in waiting and "sh040" not in waiting
    assert "its fill layer sh010.tween.v002.usda is not there (its review layer is)" in missing
    assert "<td>v002</td>" in missing and "sh040.tween.v002.usdc" in missing
    assert 'id="decided"' not in page
