"""What a command reads: a regular file, or one phrase saying what the path is instead.

Every reader of a user's file (shots, takes, clips, BVH, mapping files) says it in these
words, so that a folder, a pipe, a device or a dangling link reads the same from every
command: a pipe would block a reader for ever, a device can read without end.
"""

from __future__ import annotations

import errno
import math
import os
import re
import stat
import zipfile
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


class NotReadable(OSError):
    """A small file a command reads is not a regular file, or is larger than such a file
    gets: the one phrase saying so (``str(e)``; ``strerror`` is None)."""


def read_small_text(path: str | Path, limit: int, kind: str) -> str:
    """The UTF-8 text of ``path``, a small file (a model's JSON, a recipe's TOML) of at most
    ``limit`` bytes. Opened without blocking and checked as opened, so a pipe (which would
    block a reader for ever) or a device (which reads without end) is NotReadable at once,
    and so is a file over ``limit`` bytes (read no further); FileNotFoundError, other
    OSErrors and UnicodeDecodeError as reading raises them."""
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    try:
        mode = os.fstat(fd).st_mode
    except OSError:
        os.close(fd)
        raise
    if not stat.S_ISREG(mode):
        os.close(fd)
        if stat.S_ISDIR(mode):
            raise NotReadable(f"a folder, not a {kind}")
        raise NotReadable(f"not a regular file (a pipe, socket or device), not a {kind}")
    with os.fdopen(fd, "rb") as f:
        data = f.read(limit + 1)
    if len(data) > limit:
        raise NotReadable(f"larger than {limit:,} bytes, too large for a {kind}")
    return data.decode("utf-8")


def broken_link(path: str | Path) -> str | None:
    """What ``path`` is where it is a link that leads to no file: ``a link loop (it leads
    back to itself)`` or ``a link to nothing``; None otherwise (a file, a folder, nothing at
    all). A loop reads as "missing" to ``exists()``, which named the wrong trouble."""
    try:
        os.stat(path)
    except OSError as e:
        if e.errno == errno.ELOOP:
            return "a link loop (it leads back to itself)"
        return "a link to nothing" if e.errno == errno.ENOENT and os.path.lexists(path) else None
    except ValueError:  # a NUL in the name
        return None
    return None


#: The highest frame rate a file may state (fill --fps, a corpus's fps: 1,000 at most).
FPS_MAX = 1000


def frame_rate_trouble(value) -> str | None:
    """None where ``value`` (a file's ``fps``) is a number of frames a second above 0 and at
    most FPS_MAX; else the end of a line saying what it must be. 0 or a negative rate divides
    by zero in a fill, and 1e308 overflows into warnings and a line about the keys instead."""
    number = isinstance(value, int | float) and not isinstance(value, bool)
    if number and math.isfinite(value) and 0 < value <= FPS_MAX:
        return None
    return f"must be a number of frames a second above 0 and at most {FPS_MAX:,}, not {value!r}"


#: torch.load(weights_only=True)'s words for a pickle that names what only a full unpickler
#: would run (torch 2.4 and later): "GLOBAL os.system was not an allowed global", "... whose
#: module os is blocked".
_UNSAFE = re.compile(r"GLOBAL \S+ was not an allowed global|whose module \S+ is blocked", re.I)


def refused_for_safety(path: str | Path, error: Exception) -> bool:
    """Whether ``torch.load(path, weights_only=True)`` raised ``error`` because the file is a
    torch checkpoint (a zip) whose pickle names code or classes, not because it is damaged or
    foreign: a text file starting with ``c`` reads as pickle's GLOBAL opcode, so the error's
    words alone said "refused for safety" of it."""
    try:
        return zipfile.is_zipfile(path) and bool(_UNSAFE.search(str(error)))
    except OSError:
        return False
