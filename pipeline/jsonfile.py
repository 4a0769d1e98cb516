"""JSON that a person wrote: a key given twice is an error naming it and its line, not a
silent "the later one wins" (``json`` keeps the last)."""

from __future__ import annotations

import json
import re


class DuplicateKeyError(ValueError):
    """A JSON object names the same key twice."""

    def __init__(self, key: str, line: int | None):
        self.key, self.line = key, line
        where = f" (line {line})" if line else ""
        super().__init__(f"key {key!r} given twice{where}")


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
    second one); other errors are json's (ValueError)."""
    try:
        return json.loads(text, object_pairs_hook=_no_duplicates)
    except _Twice as e:
        spots = [m.start() for m in re.finditer(re.escape(json.dumps(e.key)) + r"\s*:", text)]
        line = text.count("\n", 0, spots[1]) + 1 if len(spots) > 1 else None
        raise DuplicateKeyError(e.key, line) from None
