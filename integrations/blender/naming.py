"""Names: the shot a Blender armature is exported as, and the take actions (no ``bpy``).

A take action is ``<shot>.v<NNN>.take<N>`` (``sh010_hero.v002.take1``): shot, fill version
and take, so the action list sorts by shot, then version, then take, and a name says where
its animation came from. The animator's own action is never renamed or written.
"""

from __future__ import annotations

import re
from typing import NamedTuple

_TAKE = re.compile(r"^(?P<shot>.+)\.v(?P<version>\d{3,})\.take(?P<take>\d+)$")
MAX_NAME = 63  # Blender's ID names


def safe(text: str) -> str:
    """Letters, digits, ``_`` and ``-`` only (a file name on every system, a USD-safe stem)."""
    out = re.sub(r"[^0-9A-Za-z_-]+", "_", text).strip("_")
    return out or "shot"


def shot_name(blend_file: str, armature: str) -> str:
    """``<blend file stem>_<armature>``, or the armature alone for an unsaved file."""
    stem = re.sub(r"\.blend\d*$", "", blend_file.replace("\\", "/").rsplit("/", 1)[-1])
    return safe(f"{stem}_{armature}" if stem else armature)


class TakeName(NamedTuple):
    shot: str
    version: int
    take: int


def take_action_name(shot: str, version: int, take: int) -> str:
    suffix = f".v{int(version):03d}.take{int(take)}"
    return shot[: MAX_NAME - len(suffix)] + suffix


def parse_take_name(name: str) -> TakeName | None:
    """The shot, version and take a take action's name says, or None for any other action
    (Blender's ``.001`` duplicates included: they are the animator's copies)."""
    m = _TAKE.match(name)
    if not m:
        return None
    return TakeName(m.group("shot"), int(m.group("version")), int(m.group("take")))
