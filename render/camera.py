"""Cameras: a turntable orbit or a front/side view, either following the character (the
default) or framed once on the whole motion's bounding box (``fixed``, the original view).

Following: the target is a zero-phase Gaussian low-pass of the body joint's ground path over
the whole shot (computed once, before rendering: no lag, no jitter, the walk's sway and bob
filtered out), at a constant height; the turntable orbits around it; one distance for the whole
shot, the smallest that fits the character's box around the followed point at every azimuth,
but never so far that the character's height fills less than ``MIN_HEIGHT`` of the frame.

Matrices are column-vector (OpenGL) 4x4 float32, handed to the shaders transposed.
"""

from __future__ import annotations

import numpy as np

ELEVATION_DEG = 14.0
FOV_Y_DEG = 35.0
VIEWS = ("turntable", "front", "side")
FRAMINGS = ("follow", "fixed")
FOLLOW_SIGMA_S = 0.5  # Gaussian sigma of the followed path (a walk's ~1 Hz sway is cut to <1 %)
MIN_HEIGHT = 0.45  # the character's box height fills at least this of the frame (its joints >= 40 %)


def follow_path(path: np.ndarray, fps: float, sigma_s: float = FOLLOW_SIGMA_S) -> np.ndarray:
    """Zero-phase (symmetric kernel, no lag) Gaussian low-pass of a (T, 3) path over the whole
    shot. The path is extended past each end by its point reflection (as ``filtfilt``'s odd
    padding), so a character walking at a steady speed at the first or last frame is still
    in the middle of the frame there (no pull towards the end position)."""
    from scipy.ndimage import gaussian_filter1d

    path = np.asarray(path, np.float64)
    sigma = max(float(sigma_s) * float(fps), 1e-6)
    if len(path) < 2:
        return path.copy()
    n = int(np.ceil(4.0 * sigma)) + 1
    padded = np.pad(path, ((n, n), (0, 0)), mode="reflect", reflect_type="odd")
    return gaussian_filter1d(padded, sigma, axis=0, mode="nearest", truncate=4.0)[n:-n]


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
    """Per-frame view-projection for ``mode`` in turntable | front | side.

    ``follow`` (T, 3): the smoothed followed point per frame (``follow_path``); then
    ``local_min``/``local_max`` bound the character around it (over the whole shot) and frame
    it. Without ``follow`` the camera is framed once on the motion's box (``fixed``).
    """

    def __init__(
        self,
        bbox_min,
        bbox_max,
        aspect: float,
        n_frames: int,
        mode="turntable",
        turns=1.0,
        safe=1.0,
        follow: np.ndarray | None = None,
        local_min=None,
        local_max=None,
    ):
        if mode not in VIEWS:
            raise ValueError(f"camera must be turntable, front or side, not {mode!r}")
        lo, hi = np.asarray(bbox_min, np.float64), np.asarray(bbox_max, np.float64)
        self.target = (lo + hi) / 2
        self.mode, self.turns, self.n, self.aspect = mode, turns, max(n_frames, 1), aspect
        self.start_az = 30.0 if mode == "turntable" else (0.0 if mode == "front" else 90.0)
        azimuths = np.linspace(0, 360, 37) if mode == "turntable" else [self.start_az]
        self.targets = None
        if follow is None:
            box_lo, box_hi, center = lo, hi, self.target
        else:
            follow = np.asarray(follow, np.float64).copy()
            box_lo, box_hi = np.asarray(local_min, np.float64), np.asarray(local_max, np.float64)
            # Constant height: the middle of the character's box (a walk's bob is not followed).
            follow[:, 1] = 0.0
            mid = (box_lo + box_hi) / 2
            follow += [0.0, mid[1], 0.0]
            box_lo, box_hi = box_lo - [0.0, mid[1], 0.0], box_hi - [0.0, mid[1], 0.0]
            self.targets = follow
            self.target = follow[0]
            center = np.zeros(3)
        corners = np.array(
            [[x, y, z] for x in (box_lo[0], box_hi[0]) for y in (box_lo[1], box_hi[1]) for z in (box_lo[2], box_hi[2])]
        )  # fmt: skip
        # One distance for the whole orbit, so the character does not pump in and out.
        self.distance = max(
            fit_distance(corners, center, _direction(a, ELEVATION_DEG), aspect, safe=safe) for a in azimuths
        )
        if follow is not None:
            # Never so far that the character's height fills less than MIN_HEIGHT of the frame.
            height = float(box_hi[1] - box_lo[1])
            self.distance = min(self.distance, height / (2 * np.tan(np.radians(FOV_Y_DEG) / 2) * MIN_HEIGHT))
            self.distance = max(self.distance, 1e-3 + np.linalg.norm(box_hi - box_lo) * 0.5)
        else:
            self.distance = max(self.distance, 1e-3 + np.linalg.norm(hi - lo) * 0.5)
        self.near = max(self.distance * 0.02, 1e-3)
        self.far = self.distance * 20 + np.linalg.norm(hi - lo) * 4

    def azimuth(self, i: int) -> float:
        if self.mode != "turntable":
            return self.start_az
        return self.start_az + 360.0 * self.turns * i / self.n

    def target_at(self, i: int) -> np.ndarray:
        if self.targets is None:
            return self.target
        return self.targets[min(max(int(i), 0), len(self.targets) - 1)]

    def eye(self, i: int) -> np.ndarray:
        return self.target_at(i) + self.distance * _direction(self.azimuth(i), ELEVATION_DEG)

    def view(self, i: int) -> np.ndarray:
        return look_at(self.eye(i), self.target_at(i))

    def projection(self, flip_y: bool = False) -> np.ndarray:
        proj = perspective(FOV_Y_DEG, self.aspect, self.near, self.far)
        if flip_y:  # render upside down so glReadPixels rows come out top-first (no flip copy)
            proj = np.diag([1.0, -1.0, 1.0, 1.0]) @ proj
        return proj

    def view_proj(self, i: int, flip_y: bool = True) -> np.ndarray:
        return (self.projection(flip_y) @ self.view(i)).astype(np.float32)

    def height_fraction(self, i: int, points: np.ndarray) -> float:
        """The fraction of the frame height that ``points`` (N, 3, world) span on screen at frame ``i``."""
        p = np.c_[np.asarray(points, np.float64), np.ones(len(points))] @ (self.projection() @ self.view(i)).T
        y = p[:, 1] / p[:, 3]
        return float((y.max() - y.min()) / 2)
