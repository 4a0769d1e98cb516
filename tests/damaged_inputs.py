"""Damaged stand-ins for the small files a command reads (a model folder's JSON, a recipe, a
library manifest): a pipe, which would block a reader for ever; a link to /dev/zero, which
reads without end; text nested too deeply for a parser."""

from __future__ import annotations

import os
from pathlib import Path

DEEP_JSON = "[" * 100_000 + "]" * 100_000
DEEP_TOML = "a = " + "[" * 100_000 + "]" * 100_000 + "\n"


def linked_copy(src: Path, dst: Path) -> Path:
    """``dst`` holding a link to each of ``src``'s files and folders (the networks are not
    copied): a file then damaged in ``dst`` is replaced, never written through its link."""
    dst.mkdir(parents=True)
    for p in src.iterdir():
        (dst / p.name).symlink_to(p)
    return dst


def replace_with(path: Path, how: str, payload: str = DEEP_JSON) -> None:
    """``path`` replaced by a pipe (``fifo``), a link to /dev/zero (``zero``) or ``payload``."""
    path.unlink(missing_ok=True)
    if how == "fifo":
        os.mkfifo(path)
    elif how == "zero":
        path.symlink_to("/dev/zero")
    else:
        path.write_text(payload)
