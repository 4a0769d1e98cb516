"""Decisions from the page: ``tween approve`` and ``tween publish``'s own functions
(:mod:`pipeline.usd.dailies`), after checking the page saw the shot's latest version.

One decision at a time in this server (a lock): of two browsers approving the same fill,
one wins and the other is told it is already approved. Writers in other processes (the CLI)
are kept apart by the fill folder's lock inside ``approve`` itself, which refuses a fill
that is already approved.
"""

from __future__ import annotations

import threading
from pathlib import Path

from dailies import tracker as trackers
from dailies.shots import Shot, find, forget, shot_file
from pipeline.errors import TweenError
from pipeline.usd import dailies, write

_lock = threading.Lock()
#: Approval layers this server sent to a tracker (an upload is a comment: never twice).
_sent: dict[str, dict] = {}


class Refused(TweenError):
    """A decision the page cannot take: the one line says why (HTTP 409)."""


def _current(roots: list[Path], key: str, version: int | None) -> tuple[Shot, str]:
    shot = find(roots, key)
    if shot is None:
        raise LookupError(key)
    n, path = shot.latest
    if version is not None and version != n:
        d = dailies.decision(path)
        if d and d.get("status") == "approved":
            note = f' ("{d["note"]}")' if d.get("note") else ""
            raise Refused(f"{shot.stem}: already approved: take {d['take']} by {d.get('by') or 'unknown'} "
                          f"at {d.get('at')}{note}, in v{n:03d}; this page showed v{version:03d}")  # fmt: skip
        raise Refused(
            f"{shot.stem}: stale: the latest is v{n:03d}, this page showed v{version:03d}; reload it"
        )
    shot_path = shot_file(shot)
    if shot_path is None:
        raise Refused(
            f"{shot.stem}: the animator's shot of {path.name} is not found (its review layer names none)"
        )
    if write.shot_stem(str(shot_path)) != shot.stem:  # its layers were copied from another shot
        raise Refused(f"{shot.stem}: {path.name} is a fill of {shot_path.name}, not of a shot {shot.stem}")
    return shot, str(shot_path)


def approve(
    roots: list[Path], key: str, take: int, note: str | None, version: int | None, by: str | None = None
) -> dict:
    """Approves ``take`` of the shot's latest fill (that must be ``version`` when given), as
    ``by`` (the name typed on the page; else the user the server runs as)."""
    with _lock:
        shot, shot_path = _current(roots, key, version)
        try:
            return dailies.approve(shot_path, take, note=note, out_dir=str(shot.folder), by=by)
        except TweenError as e:
            raise Refused(str(e)) from None
        finally:
            forget()


def publish(roots: list[Path], key: str, version: int | None) -> dict:
    """Publishes the approved take of the shot's latest fill (that must be ``version``)."""
    with _lock:
        shot, shot_path = _current(roots, key, version)
        try:
            return dailies.publish(shot_path, out_dir=str(shot.folder))
        except TweenError as e:
            raise Refused(str(e)) from None
        finally:
            forget()


def send(roots: list[Path], key: str, version: int | None, tracker, mapping: dict | None = None) -> dict:
    """Sends the approved take of the shot's latest fill (``version``) to ``tracker``, once."""
    with _lock:
        shot, _ = _current(roots, key, version)
        done = _sent.get(str(shot.latest[1]))
        if done:
            raise Refused(f"{shot.stem}: v{shot.latest[0]:03d} was already sent to {done['tracker']} "
                          f"({done['sequence']}/{done['shot']})")  # fmt: skip
        try:
            out = trackers.send(roots, key, tracker, mapping)
        except trackers.TrackerError as e:
            raise Refused(str(e)) from None
        _sent[str(shot.latest[1])] = out
        return out
