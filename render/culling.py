"""Static triangles drawn by the runs of them that can be on screen.

A long shot's ground path and key marks are hundreds of thousands of triangles, and llvmpipe
sets up every one on every frame, in view or not: the time per frame grew with the shot's
length (3.4 ms at 10,000 frames, 22 ms at 100,000). Cut into runs of consecutive triangles,
each with its bounding box, a frame draws only the runs whose box is not wholly outside the
view: the same pixels (a run outside the view volume has no fragment), for the triangles
near the camera.
"""

from __future__ import annotations

import itertools

import numpy as np

#: Vertices in a run: 256 segments of a path's ribbon, a multiple of 3 (no triangle is split).
#: Smaller runs cull closer to the view and cost more boxes to test each frame.
RUN = 1536
#: How far past a clip plane (in w) a box must lie to be culled: float32 GL against the
#: float64 test must not cull a triangle that grazes the view's edge.
MARGIN = 1e-4
_CORNERS = np.array(list(itertools.product((0, 1), repeat=3)), bool)  # (8, 3)


class Runs:
    """The triangles ``data`` ((N, 4) x, y, z, frame; N a multiple of 3) in runs of RUN
    vertices, with the 8 corners of each run's box."""

    def __init__(self, data: np.ndarray):
        pos = np.asarray(data, np.float64)[:, :3]
        self.first = np.arange(0, len(pos), RUN)
        self.count = np.minimum(RUN, len(pos) - self.first)
        lo = np.minimum.reduceat(pos, self.first, axis=0)
        hi = np.maximum.reduceat(pos, self.first, axis=0)
        corners = np.where(_CORNERS[None], hi[:, None], lo[:, None])  # (R, 8, 3)
        t = np.asarray(data, np.float64)[:, 3]
        self.t_lo, self.t_hi = np.minimum.reduceat(t, self.first), np.maximum.reduceat(t, self.first)
        self.corners = np.concatenate([corners, np.ones((*corners.shape[:2], 1))], axis=2)

    def visible(self, vp: np.ndarray) -> np.ndarray:
        """Which runs may be on screen under the view-projection ``vp`` (4x4, column vectors):
        a run is culled when all 8 corners of its box lie outside one plane of the view volume."""
        clip = self.corners @ np.asarray(vp, np.float64).T  # (R, 8, 4)
        w = clip[..., 3:] + MARGIN * np.abs(clip[..., 3:])
        xyz = clip[..., :3]
        return ~((xyz < -w).all(axis=1).any(axis=1) | (xyz > w).all(axis=1).any(axis=1))

    def near(self, frame: float, reach: float) -> np.ndarray:
        """Which runs hold a frame within ``reach`` of ``frame`` (the trail a frame draws)."""
        return (self.t_hi >= frame - reach) & (self.t_lo <= frame + reach)

    def spans(self, keep: np.ndarray) -> list[tuple[int, int]]:
        """The (first vertex, count) spans that draw the runs ``keep`` selects, adjacent runs
        as one draw call."""
        idx = np.flatnonzero(keep)
        if not len(idx):
            return []
        breaks = np.flatnonzero(np.diff(idx) > 1)
        starts, ends = idx[np.r_[0, breaks + 1]], idx[np.r_[breaks, len(idx) - 1]]
        return [
            (int(self.first[a]), int(self.first[b] + self.count[b] - self.first[a]))
            for a, b in zip(starts, ends, strict=True)
        ]

    def points(self, keep: np.ndarray) -> np.ndarray:
        """The box corners of the runs ``keep`` selects ((K, 3) world points): what bounds
        them on screen (``raster.screen_rect``)."""
        return self.corners[keep, :, :3].reshape(-1, 3)
