"""Errors the user can act on: one line naming the file (and line or prim) and the problem."""

import errno

#: errnos of a write that ran out of room: the disk, a quota, a file-size limit.
DISK_FULL = (errno.ENOSPC, errno.EFBIG, errno.EDQUOT)


def printable(text) -> str:
    """``text`` as one printable line: control characters (a newline or an escape code in a
    file name) written as Python writes them (``\\n``, ``\\x1b``), the rest as it is."""
    text = str(text)
    return text if text.isprintable() else "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


class TweenError(Exception):
    """Base of every error the CLI reports as a one-line message with a non-zero exit."""


class MotionFormatError(TweenError):
    """A motion file (BVH) is malformed."""

    def __init__(self, path, line: int | None, message: str):
        self.path, self.line = str(path), line
        where = f"{self.path}:{line}" if line is not None else self.path
        super().__init__(f"{where}: {message}")


class ShotError(TweenError):
    """A USD shot cannot be read, mapped or filled."""

    def __init__(self, shot, message: str, prim: str | None = None):
        self.shot, self.prim = str(shot), prim
        where = f"{self.shot} {prim}" if prim else self.shot
        super().__init__(f"{where}: {message}")
