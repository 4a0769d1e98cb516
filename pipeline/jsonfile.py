"""JSON that a person wrote: a key given twice is an error naming it and its line, not a
silent "the later one wins" (``json`` keeps the last); nesting too deep for Python's reader
is a ValueError like json's own errors, not a RecursionError."""

from __future__ import annotations

import json
import re


class DuplicateKeyError(ValueError):
    """A JSON object names the same key twice."""

    def __init__(self, key: str, line: int | None):
        self.key, self.line = key, line
        where = f" (line {line})" if line else ""
        super().__init__(f"key {key!r} given twice{where}")


class TooDeepError(ValueError):
    """A JSON text nests arrays or objects deeper than Python's reader goes."""

    def __init__(self):
        super().__init__("not valid JSON: arrays or objects nested too deeply to read")


class _Twice(Exception):
    def __init__(self, key: str):
        self.key = key


def _no_duplicates(pairs):
    seen = set()
    for k, _ in pairs:
        if k in seen:
            raise _Twice(k)
        seen.add(k)
    return dict(pairs)


def loads(text: str):
    """``json.loads`` that refuses duplicate keys (DuplicateKeyError, with the line of the
    second one) and nesting too deep to read (TooDeepError); other errors are json's
    (ValueError)."""
    try:
        return json.loads(text, object_pairs_hook=_no_duplicates)
    except _Twice as e:
        spots = [m.start() for m in re.finditer(re.escape(json.dumps(e.key)) + r"\s*:", text)]
        line = text.count("\n", 0, spots[1]) + 1 if len(spots) > 1 else None
        raise DuplicateKeyError(e.key, line) from None
    except RecursionError:
        raise TooDeepError() from None
