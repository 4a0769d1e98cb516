"""What the renderer draws: triangles whose points (and normals) are made per frame."""

from __future__ import annotations

import numpy as np


def sample_frames(n_frames: int, samples: int = 96) -> np.ndarray:
    """Up to ``samples`` evenly spaced frame indices of ``n_frames`` (all of them on short shots)."""
    return np.unique(np.linspace(0, n_frames - 1, min(samples, n_frames)).round().astype(int))


class Geometry:
    """Triangles (M, 3) whose N points (and smooth normals, or None for flat shading) are made
    per frame on demand, so a long shot of a dense mesh never holds every frame in memory."""

    def __init__(self, tris: np.ndarray, n_points: int, n_frames: int, frame_fn, smooth: bool = False):
        self.tris, self.n_points, self.n_frames, self.smooth = tris, n_points, n_frames, smooth
        self._fn = frame_fn

    @classmethod
    def from_arrays(cls, tris, points: np.ndarray, normals: np.ndarray | None = None) -> Geometry:
        """All frames given: ``points`` (T, N, 3), ``normals`` (T, N, 3) or None."""
        fn = (lambda i: (points[i], None)) if normals is None else (lambda i: (points[i], normals[i]))
        return cls(tris, points.shape[1], points.shape[0], fn, normals is not None)

    def frame(self, i: int) -> tuple[np.ndarray, np.ndarray | None]:
        return self._fn(i)

    def bounds(self, samples: int = 96) -> tuple[np.ndarray, np.ndarray]:
        """(min, max) over up to ``samples`` evenly spaced frames (all frames on short shots)."""
        _, lo, hi = self.frame_bounds(samples)
        return lo.min(0), hi.max(0)

    def frame_bounds(self, samples: int = 96) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(frame indices (S,), per-frame min (S, 3), per-frame max (S, 3)) at up to ``samples``
        evenly spaced frames (all frames on short shots)."""
        idx = sample_frames(self.n_frames, samples)
        pts = [self.frame(int(i))[0] for i in idx]
        return idx, np.array([p.min(0) for p in pts]), np.array([p.max(0) for p in pts])
