"""An OpenTimelineIO timeline per shot beside its review media: one track per take.

``<out>/<shot>[_vNNN].otio`` holds one video track per take rendered into that folder (named
``take1``..., or ``main`` for a shot without takes), each with one clip whose media is the
take's MP4 (an ``ExternalReference`` with a URL relative to the timeline), and a marker on every
key frame. Times are in the shot's own frame numbers at the movie's rate: the clip's available
and source range start at the first frame number (1001), so a marker's time is the key's frame
number. Each render of a take replaces that take's track and keeps the others, so rendering
the takes one after another (``--all-takes``, the farm) builds the whole timeline.
"""

from __future__ import annotations

import fcntl
import os
import re
from contextlib import contextmanager
from fractions import Fraction
from pathlib import Path

from render.output import write_whole

TRACK_KEY = "tween"


def _take_number(take) -> int | None:
    m = re.fullmatch(r"take(\d+)", str(take or ""))
    return int(m.group(1)) if m else None


@contextmanager
def folder_lock(folder: str | Path):
    """An exclusive lock on ``folder`` (flock on the directory itself: no lock file is left)."""
    fd = os.open(str(folder), os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)


def take_track(
    mp4_name: str,
    rate: Fraction | float,
    frame_numbers,
    key_frames,
    take: str | None,
    facts: dict,
    extra: dict | None = None,
):
    """The track of one take: a clip of its MP4 (``mp4_name``, relative to the timeline) with a
    marker on each key frame (``key_frames``: frame numbers among ``frame_numbers``)."""
    import opentimelineio as otio

    r = float(rate)
    frames = [int(f) for f in frame_numbers]
    first = frames[0]
    span = otio.opentime.TimeRange(
        otio.opentime.RationalTime(first, r), otio.opentime.RationalTime(len(frames), r)
    )
    meta = {
        "take": take or "",
        "take_number": _take_number(take),
        "model": str(facts.get("model", "")),
        "model_hash": str(facts.get("model_hash", "")),
        "seed": facts.get("seed"),
        "frame_range": [first, frames[-1]],
        "rate": [Fraction(rate).numerator, Fraction(rate).denominator],
        **(extra or {}),
    }
    ref = otio.schema.ExternalReference(target_url=mp4_name, available_range=span)
    clip = otio.schema.Clip(name=Path(mp4_name).stem, media_reference=ref, source_range=span)
    clip.metadata[TRACK_KEY] = dict(meta)
    index = {f: i for i, f in enumerate(frames)}
    for k in key_frames:
        i = index.get(int(k))
        if i is None:
            continue
        clip.markers.append(
            otio.schema.Marker(
                name=f"KEY {int(k)}",
                marked_range=otio.opentime.TimeRange(
                    otio.opentime.RationalTime(first + i, r), otio.opentime.RationalTime(0, r)
                ),
                color=otio.schema.MarkerColor.ORANGE,
                metadata={TRACK_KEY: {"frame": int(k)}},
            )
        )
    track = otio.schema.Track(name=take or "main", kind=otio.schema.TrackKind.Video)
    track.metadata[TRACK_KEY] = dict(meta)
    track.append(clip)
    return track


def _align(tracks: list) -> object:
    """Lines the takes' tracks up on the shot's frame numbers: each track starts with a gap as
    long as its first frame is after the earliest track's (takes rendered over different
    ``--frames``); returns that earliest frame, the timeline's global start."""
    import opentimelineio as otio

    for t in tracks:  # the gaps an earlier alignment put there
        while len(t) and isinstance(t[0], otio.schema.Gap):
            del t[0]
    starts = [t.find_clips()[0].source_range.start_time for t in tracks]
    first = min(starts, key=lambda rt: rt.to_seconds())
    for t, start in zip(tracks, starts, strict=True):
        lead = start - first.rescaled_to(start.rate)
        if lead.value > 0:
            t.insert(
                0,
                otio.schema.Gap(
                    source_range=otio.opentime.TimeRange(otio.opentime.RationalTime(0, start.rate), lead)
                ),
            )
    return first


def update_timeline(existing: str | Path | None, out_path: str | Path, shot: str, track, facts: dict,
                    keep=lambda url: True) -> str:  # fmt: skip
    """Writes ``out_path``: the timeline of ``existing`` (if it reads) with ``track`` replacing
    the track of the same take (the others kept while ``keep(their media URL)``), sorted by
    take number, and lined up on the shot's frame numbers (:func:`_align`)."""
    import opentimelineio as otio

    tracks = []
    if existing is not None and Path(existing).exists():
        try:
            old = otio.adapters.read_from_file(str(existing))
            tracks = [t for t in old.tracks if isinstance(t, otio.schema.Track)]
        except Exception:  # a damaged or foreign file: rebuilt from this take
            tracks = []
    take = track.metadata[TRACK_KEY]["take"]
    kept = []
    for t in tracks:
        meta = dict(t.metadata.get(TRACK_KEY, {}))
        clips = list(t.find_clips())
        url = (
            clips[0].media_reference.target_url
            if clips and hasattr(clips[0].media_reference, "target_url")
            else ""
        )
        if meta.get("take", t.name) != take and keep(url):
            kept.append(t.deepcopy())
    kept.append(track)
    kept.sort(key=lambda t: (t.metadata[TRACK_KEY].get("take_number") is None,
                             t.metadata[TRACK_KEY].get("take_number") or 0, t.name))  # fmt: skip
    first = _align(kept)
    tl = otio.schema.Timeline(name=shot, global_start_time=first)
    tl.metadata[TRACK_KEY] = {
        "shot": shot,
        "model": str(facts.get("model", "")),
        "model_hash": str(facts.get("model_hash", "")),
        "takes": [t.metadata[TRACK_KEY].get("take") for t in kept],
    }
    for t in kept:
        t.metadata[TRACK_KEY] = dict(t.metadata[TRACK_KEY])
        tl.tracks.append(t)
    out_path = str(out_path)
    write_whole(out_path, otio.adapters.write_to_string(tl, "otio_json").encode(), "timeline")
    return out_path
