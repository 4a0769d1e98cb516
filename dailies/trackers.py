"""The trackers by name (``tween dailies --tracker NAME``): each one a class behind the
:class:`dailies.tracker.Tracker` interface, made from its settings. A new tracker (ftrack,
ShotGrid) is one entry here and one module beside ``kitsu.py``."""

from __future__ import annotations

from dailies.kitsu import Kitsu
from dailies.tracker import Tracker, TrackerError

KINDS = {"kitsu": Kitsu}


def make(name: str, settings: dict | None = None) -> Tracker:
    """The tracker called ``name``, configured from ``settings`` (else its environment)."""
    if name not in KINDS:
        raise TrackerError(f"--tracker {name!r}: unknown tracker (known: {', '.join(KINDS)})")
    return KINDS[name].from_settings(settings)
