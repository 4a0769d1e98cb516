"""Whether the terms of the capture a model learned from allow a studio to use it commercially.

One rule for every model folder's ``commercial`` (models/README.md): commercial use only where
every source's terms are known to allow it. A licence that forbids it (CC BY-NC, "research
only"), forbids derivatives (weights are one), or is not known (not stated, unknown) is not.
"""

from __future__ import annotations

import re

#: Terms that rule commercial use of a model out, or leave it unknown.
NOT_COMMERCIAL = re.compile(
    r"\bNC\b|\bND\b|non-?commercial|no[- ]derivatives|research only|not stated|unknown", re.IGNORECASE
)


def commercial(licences) -> bool:
    """True only where there is a licence and every one of ``licences`` allows commercial use."""
    licences = list(licences)
    return bool(licences) and not any(NOT_COMMERCIAL.search(str(t)) for t in licences)
