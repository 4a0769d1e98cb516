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


#: Terms under which no model may be trained and shipped: "no derivatives" (CC BY-ND, ND,
#: NoDerivatives, NoDerivs), "research only" (or academic only, for research purposes only),
#: and "not for training" / "no (AI) training".
NOT_TRAINABLE = re.compile(
    r"\bND\b|no[- ]?deriv|\b(?:research|academic)(?:[- ]use| purposes?)? only\b"
    r"|\bnot? (?:to be used )?for (?:ai |ml |machine[- ]learning |model )?training\b"
    r"|\bno (?:ai |ml |machine[- ]learning |model )?training\b",
    re.IGNORECASE,
)


def forbids_training(licence) -> str | None:
    """The words of ``licence`` that forbid training a model that ships, or None where it may.

    The project's data rule (issue 30) trains on capture whose terms allow training *and*
    shipping the weights. Weights learned from capture are an adaptation of it, so "no
    derivatives" (ND) forbids sharing them, and "research only" (or "not for training") forbids
    a production model outright. Non-commercial terms (CC BY-NC) do not: they allow adapting
    and sharing, only not for commercial use, so such a source trains, and :func:`commercial`
    marks the model's weights non-commercial at export (``commercial: false`` in model.json).
    """
    m = NOT_TRAINABLE.search(str(licence))
    return m.group(0) if m else None
