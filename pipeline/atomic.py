"""A file replaced whole or not at all: written beside its destination under a temporary
name and renamed over it, so a reader (or an interrupted writer) never sees half of it; and
whether a folder may be written in, or a file rewritten, at all."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def writable(path: str | Path) -> bool:
    """Whether this process may write in the folder ``path``, or rewrite the file ``path``, by
    its access and by its mode bits: a read-only (published) folder or layer stays untouched
    even for root, whom access lets write."""
    return os.access(path, os.W_OK) and bool(Path(path).stat().st_mode & 0o222)


@contextmanager
def replacing(path: str | Path, suffix: str = ".tmp") -> Iterator[Path]:
    """A temporary file beside ``path`` (``.NAME.XXXX`` + ``suffix``) for the block to write,
    with the mode a file the user writes gets (mkstemp makes it private); renamed over
    ``path`` when the block ends, removed when it fails."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=suffix)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
