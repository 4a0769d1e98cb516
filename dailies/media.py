"""Review media served from under the roots only: a URL names a root by index and a path
under it; the file it resolves to (symlinks followed) must lie under one of the roots."""

from __future__ import annotations

import os
from pathlib import Path
from urllib.parse import quote

#: What the page plays or shows; nothing else (layers, shots) is served.
TYPES = {".mp4": "video/mp4", ".png": "image/png", ".jpg": "image/jpeg", ".otio": "application/json"}


def url(roots: list[Path], path: Path | None) -> str | None:
    """``/media/<root>/<path under it>`` for a file under a root (as found, links unresolved)."""
    if path is None:
        return None
    for i, root in enumerate(roots):
        try:
            rel = Path(path).relative_to(root)
        except ValueError:
            continue
        return f"/media/{i}/{quote(rel.as_posix())}"
    return None


def resolve(roots: list[Path], index: int, rel: str) -> Path | None:
    """The file ``rel`` under root ``index``, or None: outside every root once symlinks are
    followed, not a media type, missing, or not a regular file."""
    if not 0 <= index < len(roots) or "\0" in rel or Path(rel).suffix.lower() not in TYPES:
        return None
    try:  # a name too long for a path (ENAMETOOLONG) is no media either
        real = Path(os.path.realpath(roots[index] / rel))
        inside = any(real == r or real.is_relative_to(r) for r in (Path(os.path.realpath(x)) for x in roots))
        # What the name leads to is media too: a link named .mp4 to a layer was a 500 (no type).
        return real if inside and real.is_file() and real.suffix.lower() in TYPES else None
    except OSError:
        return None
