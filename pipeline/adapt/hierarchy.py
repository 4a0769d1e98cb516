"""Walks over a joint hierarchy given as a parent index per joint (-1 for a root): what the
convention mapping (mapping.py) and the word-based limb chains (chains.py) both read."""

from __future__ import annotations

import numpy as np


def depths(parents: np.ndarray) -> np.ndarray:
    """(J,) each joint's depth below its root (parents come before their children)."""
    d = np.zeros(len(parents), np.int64)
    for j, p in enumerate(parents):
        d[j] = d[p] + 1 if p >= 0 else 0
    return d


def ancestors(parents, j) -> list[int]:
    """``j``, its parent, …, its root."""
    out = []
    while j >= 0:
        out.append(int(j))
        j = parents[j]
    return out


def common_ancestor(parents: np.ndarray, joints) -> int | None:
    """The lowest joint every one of ``joints`` is (or descends from); None in a forest."""
    paths = [ancestors(parents, j) for j in joints]
    shared = set(paths[0]).intersection(*paths[1:])
    return next((a for a in paths[0] if a in shared), None)


def path_below(parents: np.ndarray, top: int, end: int) -> list[int]:
    """The joints from below ``top`` down to ``end`` (``end`` included), top first; [] where
    ``end`` does not descend from ``top``."""
    up = ancestors(parents, end)
    return up[: up.index(top)][::-1] if top in up else []
