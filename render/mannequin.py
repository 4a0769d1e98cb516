"""A stand-in body for skeletons without skinned meshes: one capsule per bone, a sphere for the head.

Built in numpy from joint world positions each frame (capsules are rotationally symmetric, so
only the bone's axis matters), with exact smooth normals.
"""

from __future__ import annotations

import numpy as np

from render.geometry import Geometry

_SEG = 12  # around the axis
_RINGS = 4  # per hemisphere


def _template():
    """Per-vertex (base, extra, radial, theta): pos = p + a*(base*L + extra*r) + r*radial*dir(theta)."""
    rows = []
    for i in range(_RINGS + 1):  # bottom hemisphere, pole to equator
        phi = np.pi / 2 * i / _RINGS
        rows.append((0.0, -np.cos(phi), np.sin(phi)))
    for i in range(_RINGS + 1):  # top hemisphere, equator to pole
        phi = np.pi / 2 * i / _RINGS
        rows.append((1.0, np.sin(phi), np.cos(phi)))
    theta = 2 * np.pi * np.arange(_SEG) / _SEG
    verts = np.array([(b, e, r, th) for (b, e, r) in rows for th in theta], np.float32)
    tris = []
    for i in range(len(rows) - 1):
        for j in range(_SEG):
            a, b = i * _SEG + j, i * _SEG + (j + 1) % _SEG
            c, d = a + _SEG, b + _SEG
            tris += [(a, b, d), (a, d, c)]
    return verts, np.array(tris, np.int32)


_VERTS, _TRIS = _template()


class Mannequin:
    """Capsules over joint positions (T, J, 3); sizes fixed from the first frame."""

    def __init__(self, joints: np.ndarray, parents, names, skip_from=()):
        self.joints = np.asarray(joints, np.float32)
        self.parents, self.names = np.asarray(parents), list(names)
        self.skip = frozenset(int(j) for j in skip_from)
        self.tris, pts, _ = capsules(self.joints[:1], self.parents, self.names, skip_from=self.skip)
        self.n_points = pts.shape[1]

    def frame(self, i: int):
        _, pts, nrm = capsules(
            self.joints[i : i + 1], self.parents, self.names, self.joints[0], skip_from=self.skip
        )
        return pts[0], nrm[0]

    def geometry(self):

        return Geometry(self.tris, self.n_points, len(self.joints), self.frame, smooth=True)


def capsules(joints: np.ndarray, parents, names, sizing: np.ndarray | None = None, skip_from=()):
    """Triangles, per-frame points (T, N, 3) and normals for joint positions (T, J, 3).

    Radii come from ``sizing`` (J, 3) joint positions (default: the first frame), so a
    character keeps its proportions whatever pose a frame is in. Bones from the joints in
    ``skip_from`` (a static root bone above the hips) are not drawn, nor counted in the height.
    """
    joints = np.asarray(joints, np.float32)
    parents = np.asarray(parents)
    ref = joints[0] if sizing is None else np.asarray(sizing, np.float32)
    body = [j for j in range(len(parents)) if j not in skip_from] if skip_from else slice(None)
    height = float(np.ptp(ref[body, 1])) or float(np.ptp(ref[body], axis=0).max()) or 1.0
    starts, ends, radii = [], [], []
    for j, p in enumerate(parents):
        if p < 0 or p in skip_from:
            continue
        length = float(np.linalg.norm(ref[j] - ref[p]))
        if length < 1e-4 * height:
            continue
        starts.append(p)
        ends.append(j)
        radii.append(np.clip(0.2 * length, 0.012 * height, 0.045 * height))
    p0, p1 = joints[:, starts], joints[:, ends]  # (T, B, 3)
    r = np.array(radii, np.float32)[None, :].repeat(len(joints), 0)
    # The head has no end joint in most mocap skeletons: give leaves named "head" a skull.
    is_parent = set(parents[parents >= 0].tolist())
    for j, n in enumerate(names):
        if j not in is_parent and "head" in n.lower() and parents[j] >= 0:
            a = joints[:, j] - joints[:, parents[j]]
            a /= np.linalg.norm(a, axis=-1, keepdims=True) + 1e-9
            rh = 0.065 * height
            c = joints[:, j] + a * rh * 0.7
            p0 = np.concatenate([p0, c[:, None]], 1)
            p1 = np.concatenate([p1, (c + a * 1e-4)[:, None]], 1)
            r = np.concatenate([r, np.full((len(joints), 1), rh, np.float32)], 1)
    return _sweep(p0, p1, r)


def _sweep(p0, p1, r):
    T, B = p0.shape[:2]
    axis = p1 - p0
    length = np.linalg.norm(axis, axis=-1, keepdims=True)
    a = axis / np.maximum(length, 1e-9)
    helper = np.where(
        np.abs(a[..., 2:3]) > 0.9, np.array([1, 0, 0], np.float32), np.array([0, 0, 1], np.float32)
    )
    u = np.cross(a, helper)
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    v = np.cross(a, u)
    base, extra, radial, th = (_VERTS[:, k] for k in range(4))
    d = np.cos(th)[None, None, :, None] * u[:, :, None] + np.sin(th)[None, None, :, None] * v[:, :, None]
    nrm = extra[None, None, :, None] * a[:, :, None] + radial[None, None, :, None] * d
    rr = r[:, :, None, None]
    pts = p0[:, :, None] + a[:, :, None] * (base[None, None, :, None] * length[:, :, None]) + rr * nrm
    V = len(_VERTS)
    tris = (_TRIS[None] + (V * np.arange(B))[:, None, None]).reshape(-1, 3).astype(np.int32)
    return tris, pts.reshape(T, B * V, 3).astype(np.float32), nrm.reshape(T, B * V, 3).astype(np.float32)
