"""Sending an approved take to the studio's tracker: the interface, and what is sent.

A tracker is anything with ``send(take) -> dict`` (:class:`Tracker`); :mod:`dailies.trackers`
names the ones built in (Kitsu, :mod:`dailies.kitsu`), so ftrack or ShotGrid is one more
class and one entry there, not a change to the page or the CLI.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from dailies.detail import media
from dailies.shots import Shot, cached, find, layer_info
from pipeline import jsonfile
from pipeline.errors import TweenError
from pipeline.inputs import read_small_text

#: The most a tracker mapping file holds: a stem and two names per shot, for thousands of shots.
MAPPING_LIMIT = 4 * 1024 * 1024
#: ``SEQ_SHOT.usda`` (``sq010_sh0020``): sequence and shot from the file name.
NAME = re.compile(r"^(?P<sequence>[^_.]+)_(?P<shot>[^.]+)$")


class TrackerError(TweenError):
    """The tracker refused, or the shot or its task is not there: one line says which."""


@dataclass(frozen=True)
class ApprovedTake:
    """What a tracker gets: where it goes (sequence, shot) and what (the take's MP4, the note)."""

    sequence: str
    shot: str
    take: int
    mp4: Path
    note: str
    by: str
    at: str
    layer: str  # the fill layer that records the approval


class Tracker(Protocol):
    name: str

    def send(self, take: ApprovedTake) -> dict:
        """Uploads the take; returns what the page shows ({"tracker", "task", "status", ...})."""


def names(stem: str, folder: Path, mapping: dict | None = None) -> tuple[str, str]:
    """(sequence, shot) for the tracker: the mapping's entry for the file stem, else
    ``SEQ_SHOT`` from the file name, else the folder's name and the stem."""
    if mapping and stem in mapping:
        entry = mapping[stem]
        if not isinstance(entry, dict) or not entry.get("sequence") or not entry.get("shot"):
            raise TrackerError(f"tracker mapping: {stem!r} needs a sequence and a shot")
        return str(entry["sequence"]), str(entry["shot"])
    m = NAME.match(stem)
    if m:
        return m["sequence"], m["shot"]
    return folder.name, stem


def read_mapping(path: str | os.PathLike | None) -> dict | None:
    """A JSON object ``{"<file stem>": {"sequence": "SQ01", "shot": "SH010"}}``, or None."""
    if not path:
        return None
    try:
        data = jsonfile.loads(read_small_text(path, MAPPING_LIMIT, "tracker mapping"))
    except OSError as e:
        raise TrackerError(f"{path}: cannot read the tracker mapping: {e.strerror or e}") from None
    except ValueError as e:
        raise TrackerError(f"{path}: the tracker mapping is not JSON: {e}") from None
    if not isinstance(data, dict):
        raise TrackerError(f"{path}: the tracker mapping must be a JSON object keyed by shot file stem")
    return data


def approved_take(shot: Shot, mapping: dict | None = None) -> ApprovedTake:
    """The approved take of the shot's latest fill and its MP4, or one line saying what is missing."""
    n, path = shot.latest
    appr = dict((cached(path, layer_info) or {}).get("approval") or {})
    if appr.get("status") != "approved":
        raise TrackerError(f"{path}: nothing approved to send (the latest fill is pending)")
    take = int(appr["take"])
    mp4 = media(shot, n, [take])[take]["mp4"]
    if mp4 is None:
        raise TrackerError(f"{shot.stem}: take {take} has no review MP4 in {shot.folder / 'review'} to send")
    seq, name = names(shot.stem, shot.folder, mapping)
    return ApprovedTake(seq, name, take, mp4, str(appr.get("note") or ""), str(appr.get("by") or ""),
                        str(appr.get("at") or ""), path.name)  # fmt: skip


def send(roots: list[Path], key: str, tracker: Tracker, mapping: dict | None = None) -> dict:
    """Sends the approved take of the shot ``key`` (under ``roots``) to ``tracker``."""
    return send_take(tracker, approved_of(roots, key, mapping))


def approved_of(roots: list[Path], key: str, mapping: dict | None = None) -> ApprovedTake:
    """The approved take of the shot ``key`` under ``roots`` (:func:`approved_take`);
    LookupError when there is no such shot."""
    shot = find(roots, key)
    if shot is None:
        raise LookupError(key)
    return approved_take(shot, mapping)


def send_take(tracker: Tracker, take: ApprovedTake) -> dict:
    """Sends ``take`` to ``tracker``; what it answered, with where the take went."""
    return {"tracker": tracker.name, "sequence": take.sequence, "shot": take.shot, "take": take.take,
            **tracker.send(take)}  # fmt: skip
