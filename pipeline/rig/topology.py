"""Skeleton-aware convolution neighbourhoods (Aberman et al. 2020, as GANimator uses them).

Vertices are the J joints, then one virtual vertex per contact joint (its label), then one
virtual vertex for the root displacement, V = J + C + 1 in all.
"""

from __future__ import annotations

import numpy as np


def tree_distances(parents) -> np.ndarray:
    """(J, J) number of bones between every pair of joints."""
    parents = np.asarray(parents)
    J = len(parents)
    adj = [[] for _ in range(J)]
    for j, p in enumerate(parents):
        if p >= 0:
            adj[j].append(int(p))
            adj[int(p)].append(j)
    dist = np.full((J, J), J + 1, np.int64)
    for s in range(J):
        dist[s, s] = 0
        frontier = [s]
        while frontier:
            nxt = []
            for u in frontier:
                for v in adj[u]:
                    if dist[s, v] > dist[s, u] + 1:
                        dist[s, v] = dist[s, u] + 1
                        nxt.append(v)
            frontier = nxt
    return dist


def neighbourhoods(parents, contacts, radius: int = 2) -> list[list[int]]:
    """Each vertex's input vertices, sorted, itself included.

    - joint j: every joint within ``radius`` bones;
    - contact vertex of foot f: joined to f, and it shares f's neighbourhood;
    - root-displacement vertex: the root joint's neighbourhood, every contact vertex and
      itself; each of those vertices also sees the root-displacement vertex.
    """
    parents = np.asarray(parents)
    J, C = len(parents), len(contacts)
    R = J + C
    dist = tree_distances(parents)
    nb = [set(np.flatnonzero(dist[j] <= radius).tolist()) for j in range(J)]
    for c, f in enumerate(contacts):
        nb[int(f)].add(J + c)
    nb += [None] * C  # contact vertices alias their foot's set (filled below)
    root_set = set(nb[0]) | set(range(J, J + C)) | {R}
    for v in root_set - {R}:
        foot = int(contacts[v - J]) if v >= J else v
        nb[foot].add(R)
    for c, f in enumerate(contacts):
        nb[J + c] = nb[int(f)]
    nb.append(root_set)
    return [sorted(s) for s in nb]


def vertex_mask(nb: list[list[int]]) -> np.ndarray:
    """(V, V) 0/1: output vertex i reads input vertex j."""
    V = len(nb)
    m = np.zeros((V, V), np.float32)
    for i, s in enumerate(nb):
        m[i, s] = 1.0
    return m
