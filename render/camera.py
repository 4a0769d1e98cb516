"""Cameras: a turntable orbit or a fixed front/side view, framed from the motion's bounding box.

Matrices are column-vector (OpenGL) 4x4 float32, handed to the shaders transposed.
"""

from __future__ import annotations

import numpy as np

ELEVATION_DEG = 14.0
FOV_Y_DEG = 35.0


def look_at(eye, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    f = np.asarray(target, np.float64) - eye
    f /= np.linalg.norm(f)
    s = np.cross(f, up)
    s /= np.linalg.norm(s)
    u = np.cross(s, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = s, u, -f
    m[:3, 3] = -m[:3, :3] @ eye
    return m


def perspective(fov_y_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    f = 1.0 / np.tan(np.radians(fov_y_deg) / 2)
    m = np.zeros((4, 4))
    m[0, 0], m[1, 1] = f / aspect, f
    m[2, 2], m[2, 3] = (far + near) / (near - far), 2 * far * near / (near - far)
    m[3, 2] = -1.0
    return m


def _direction(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit vector from the target towards the camera; azimuth 0 looks from +Z (the front)."""
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    return np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])


def fit_distance(
    corners: np.ndarray, target: np.ndarray, direction: np.ndarray, aspect: float, margin=1.12, safe=1.0
) -> float:
    """Smallest distance along ``direction`` at which every corner is inside the frustum
    (vertically inside the middle ``safe`` fraction, clear of the burn-in bands)."""
    f = -direction
    s = np.cross(f, [0.0, 1.0, 0.0])
    s /= np.linalg.norm(s)
    u = np.cross(s, f)
    p = (corners - target) * margin
    ty = np.tan(np.radians(FOV_Y_DEG) / 2)
    tx = ty * aspect
    ty *= safe
    d = np.maximum(np.abs(p @ s) / tx - p @ f, np.abs(p @ u) / ty - p @ f)
    return float(d.max())


class Camera:
    """Per-frame view-projection for ``mode`` in turntable | front | side."""

    def __init__(
        self, bbox_min, bbox_max, aspect: float, n_frames: int, mode="turntable", turns=1.0, safe=1.0
    ):
        if mode not in ("turntable", "front", "side"):
            raise ValueError(f"camera must be turntable, front or side, not {mode!r}")
        lo, hi = np.asarray(bbox_min, np.float64), np.asarray(bbox_max, np.float64)
        self.target = (lo + hi) / 2
        corners = np.array(
            [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
        )
        self.mode, self.turns, self.n, self.aspect = mode, turns, max(n_frames, 1), aspect
        self.start_az = 30.0 if mode == "turntable" else (0.0 if mode == "front" else 90.0)
        azimuths = np.linspace(0, 360, 37) if mode == "turntable" else [self.start_az]
        # One distance for the whole orbit, so the character does not pump in and out.
        self.distance = max(
            fit_distance(corners, self.target, _direction(a, ELEVATION_DEG), aspect, safe=safe)
            for a in azimuths
        )
        self.distance = max(self.distance, 1e-3 + np.linalg.norm(hi - lo) * 0.5)
        self.near = max(self.distance * 0.02, 1e-3)
        self.far = self.distance * 20 + np.linalg.norm(hi - lo) * 4

    def azimuth(self, i: int) -> float:
        if self.mode != "turntable":
            return self.start_az
        return self.start_az + 360.0 * self.turns * i / self.n

    def eye(self, i: int) -> np.ndarray:
        return self.target + self.distance * _direction(self.azimuth(i), ELEVATION_DEG)

    def view_proj(self, i: int, flip_y: bool = True) -> np.ndarray:
        proj = perspective(FOV_Y_DEG, self.aspect, self.near, self.far)
        if flip_y:  # render upside down so glReadPixels rows come out top-first (no flip copy)
            proj = np.diag([1.0, -1.0, 1.0, 1.0]) @ proj
        return (proj @ look_at(self.eye(i), self.target)).astype(np.float32)
