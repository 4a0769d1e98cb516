"""The list's cost with many shots in one folder (a sequence filled into one ``--out-dir``):
each folder is listed once per request, not once per shot (that made the list grow with the
square of the shots: 1,000 shots in one folder took seconds per request)."""

import dataclasses
import os
import threading
from pathlib import Path

from dailies import shots

APPROVAL = """
            dictionary approval = {
                string at = "2024-01-02T03:04:05+00:00"
                string by = "rev"
                string note = "ok"
                string of = "%s.tween.v001.usda"
                string status = "approved"
                int take = 1
            }"""


def _layer(path: Path, approval_of: str | None = None) -> None:
    """A fill layer's metadata only (what the list reads), approved when ``approval_of``."""
    path.write_text(
        "#usda 1.0\n(\n    customLayerData = {\n        dictionary tween = {\n"
        '            string createdAt = "2024-01-01T00:00:00+00:00"\n'
        '            string model = "interp"\n            int takes = 2'
        + (APPROVAL % approval_of if approval_of else "")
        + "\n        }\n    }\n)\n"
    )


def _sequence(folder: Path, n: int) -> None:
    """``n`` shots in one folder: every third approved (a v002 approving v001), every sixth
    of those published."""
    folder.mkdir(parents=True)
    for i in range(n):
        stem = f"sh{i:04d}"
        _layer(folder / f"{stem}.tween.v001.usda")
        (folder / f"{stem}.review.v001.usda").write_text("#usda 1.0\n")
        if i % 3 == 0:
            _layer(folder / f"{stem}.tween.v002.usda", approval_of=stem)
        if i % 6 == 0:
            (folder / f"{stem}.publish.v002.usda").write_text("#usda 1.0\n")


def _listings_scans(monkeypatch, roots: list[Path]) -> tuple[list[dict], int]:
    """A cold listing then a warm one (layers read, roots walked again): the rows and how many
    times a folder was listed (``os.scandir`` is under ``os.walk`` and ``Path.glob``,
    ``os.listdir`` under ``Path.iterdir``)."""
    calls = []
    with monkeypatch.context() as m:
        for name in ("scandir", "listdir"):
            real = getattr(os, name)
            m.setattr(os, name, lambda *a, _real=real, **k: calls.append(a) or _real(*a, **k))
        rows = shots.listing(roots)
        assert shots.listing(roots) == rows
    return rows, len(calls)


def test_many_shots_in_one_folder_list_it_once_per_request(tmp_path, monkeypatch):
    counts = {}
    for n in (6, 120):
        _sequence(tmp_path / f"n{n}" / "seq", n)
        rows, counts[n] = _listings_scans(monkeypatch, [tmp_path / f"n{n}"])
        assert len(rows) == n
        by_key = {r["key"]: r for r in rows}
        assert by_key["0/seq/sh0000"]["status"] == "approved" and by_key["0/seq/sh0000"]["published"]
        assert by_key["0/seq/sh0000"]["decision"]["note"] == "ok" and by_key["0/seq/sh0000"]["version"] == 2
        assert by_key["0/seq/sh0003"]["status"] == "approved" and not by_key["0/seq/sh0003"]["published"]
        assert by_key["0/seq/sh0001"]["status"] == "pending" and by_key["0/seq/sh0001"]["version"] == 1
        assert sum(r["status"] == "approved" for r in rows) == len(range(0, n, 3))
        assert sum(r["published"] for r in rows) == len(range(0, n, 6))
    # Per request: the walk (root, seq) and one listing of seq. Before: one glob per shot more,
    # two on the first request (the decision's own glob).
    assert counts[120] == counts[6] <= 2 * 3, counts


def test_shots_in_folders_of_their_own_list_each_folder_once(tmp_path, monkeypatch):
    for i in range(5):
        _sequence(tmp_path / "shots" / f"seq{i}", 4)
    rows, count = _listings_scans(monkeypatch, [tmp_path / "shots"])
    assert len(rows) == 20 and sum(r["published"] for r in rows) == 5
    assert count <= 2 * 2 * 6  # two requests; each: the walk of 6 folders, one listing of 5


def test_an_approval_the_walk_has_not_seen_yet_is_shown(tmp_path):
    """The walk is reused for seconds; a decision taken meanwhile (a later fill version
    approving the walked latest) still shows, as ``decision`` itself reports it."""
    _sequence(tmp_path / "seq", 1)
    shot = shots.find([tmp_path], "0/seq/sh0000")
    walked = dataclasses.replace(shot, versions=shot.versions[:1])
    row = shots.summary(walked)
    assert row["version"] == 1 and row["status"] == "approved" and row["decision"]["by"] == "rev"
    assert not row["published"]  # v002 is published, not v001


def test_a_name_holding_glob_characters_is_published_by_its_own_layer(tmp_path):
    """The published layer is looked for by name, not as a pattern: ``a[1]`` is published by
    ``a[1].publish.v002.usda``, never by ``a1.publish.v002.usda`` (as fill and approve find
    such a shot's versions)."""
    for stem in ("a[1]", "b[1]"):
        _layer(tmp_path / f"{stem}.tween.v001.usda")
        _layer(tmp_path / f"{stem}.tween.v002.usda", approval_of=stem)
    (tmp_path / "a[1].publish.v002.usda").write_text("#usda 1.0\n")
    (tmp_path / "b1.publish.v002.usda").write_text("#usda 1.0\n")
    rows = {r["key"]: r for r in shots.listing([tmp_path])}
    assert rows["0/a[1]"]["status"] == rows["0/b[1]"]["status"] == "approved"
    assert rows["0/a[1]"]["published"] and not rows["0/b[1]"]["published"]


def test_a_pipe_named_like_a_later_version_holds_no_first_listing(tmp_path):
    """A FIFO named like a later fill version is not read (the list looks there for an
    approval of the walked latest): a server started beside one hung on its first listing."""
    _sequence(tmp_path / "seq", 2)
    fifo = tmp_path / "seq" / "sh0001.tween.v009.usda"
    os.mkfifo(fifo)
    done = []
    t = threading.Thread(target=lambda: done.append(shots.listing([tmp_path])), daemon=True)
    t.start()
    t.join(10)
    held = not done
    if held:  # let the reader go (a writer end opened without waiting), then fail
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        t.join(10)
    assert not held, "the listing opened the pipe"
    assert {r["key"]: r["version"] for r in done[0]} == {"0/seq/sh0000": 2, "0/seq/sh0001": 1}


def test_the_list_decides_by_tween_decision_itself(tmp_path, monkeypatch):
    """The list's decision is ``pipeline.usd.dailies``'s own (one function, given the folder's
    listing): approved, rejected, a newer pending fill, an approval of an older version all
    read as ``decision`` reads them, and a change to its rule shows in the list."""
    from pipeline.usd import dailies

    _sequence(tmp_path / "seq", 4)
    seq = tmp_path / "seq"
    _layer(seq / "sh0001.tween.v002.usda", approval_of="sh0001")
    text = (seq / "sh0001.tween.v002.usda").read_text().replace('"approved"', '"rejected"')
    (seq / "sh0001.tween.v002.usda").write_text(text)
    _layer(seq / "sh0003.tween.v003.usda")  # newer than sh0003's approval: pending again
    rows = {r["key"]: r for r in shots.listing([tmp_path])}
    assert {k: r["status"] for k, r in rows.items()} == {
        "0/seq/sh0000": "approved", "0/seq/sh0001": "rejected", "0/seq/sh0002": "pending",
        "0/seq/sh0003": "pending",
    }  # fmt: skip
    for key, row in rows.items():
        d = dailies.decision(seq / f"{row['stem']}.tween.v{row['version']:03d}.usda")
        assert row["decision"] == ({k: v for k, v in d.items() if k != "layer"} if d else None), key
    real = dailies._approval
    monkeypatch.setattr(dailies, "_approval", lambda info: (d := real(info)) and {**d, "by": d["by"].upper()})
    assert {r["key"]: r for r in shots.listing([tmp_path])}["0/seq/sh0000"]["decision"]["by"] == "REV"


def test_a_pipe_named_like_a_later_version_holds_no_decision(tmp_path):
    """``tween``'s own ``decision`` of a pending fill skips a FIFO named like a later version
    (as the list always did): it opened it and hung."""
    from pipeline.usd import dailies

    _sequence(tmp_path / "seq", 2)
    fifo = tmp_path / "seq" / "sh0001.tween.v009.usda"
    os.mkfifo(fifo)
    done = []
    t = threading.Thread(
        target=lambda: done.append(dailies.decision(fifo.with_name("sh0001.tween.v001.usda")))
    )
    t.daemon = True
    t.start()
    t.join(10)
    held = not done
    if held:
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        t.join(10)
    assert not held, "decision opened the pipe"
    assert done == [None]
