"""What a command reads: a regular file, or one phrase saying what the path is instead.

Every reader of a user's file (shots, takes, clips, BVH, mapping files) says it in these
words, so that a folder, a pipe, a device or a dangling link reads the same from every
command: a pipe would block a reader for ever, a device can read without end.
"""

from __future__ import annotations

import os
from pathlib import Path


def not_a_file(path: str | Path, kind: str) -> str | None:
    """None where ``path`` is a regular file (or a link to one); else what it is instead:
    ``file not found``, ``a link to nothing``, ``a folder, not a {kind}``, or ``not a
    regular file (a pipe, socket or device), not a {kind}``."""
    try:
        if os.path.isfile(path):
            return None
        if os.path.isdir(path):
            return f"a folder, not a {kind}"
        if os.path.exists(path):
            return f"not a regular file (a pipe, socket or device), not a {kind}"
        return "a link to nothing" if os.path.lexists(path) else "file not found"
    except (OSError, ValueError):  # a NUL in the name, a name too long
        return "file not found"
