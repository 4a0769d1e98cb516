"""Left/right mirroring of motion on a symmetric skeleton (augmentation and test-time averaging).

The world is reflected across the vertical plane normal to one horizontal axis (M). Joint j's
mirrored global frame belongs to its pair p(j) and is M·G_j·A_j, where A_j is a fixed reflection
in j's own frame that carries p(j)'s rest offsets onto j's. Locally that is

    l'_{p(j)} = A_{parent(j)} · l_j · A_j          l'_root = M · l_root · A_root

and, as A·l·A' = (−A)·l·(−A') with −A a proper rotation, a pair of quaternion products.

Written here because no rotation library knows a rig's joint pairs or its local axis
conventions. A_j is a diagonal sign matrix: the offsets fix it where a joint has an
off-axis child; where they leave a choice (a chain along one axis), the sample motion
decides, by which choice makes the mirrored mean pose of the joint closest to its pair's.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.motion.rotations import quat_mul
from pipeline.motion.skeleton import Skeleton

# The four diagonal reflections (det −1) a joint's mirror may take.
_CANDIDATES = [np.array(s, np.float64) for s in product((1, -1), repeat=3) if np.prod(s) < 0]


@dataclass(frozen=True)
class Mirror:
    """pairs[j]: j's mirror joint; signs[j]: diagonal of A_j; axis: the world axis reflected."""

    pairs: np.ndarray  # (J,) int
    signs: np.ndarray  # (J, 3) ±1
    axis: int = 2

    def _quats(self):
        # −A as a quaternion: identity when A = −I, else 180° about the axis A keeps.
        def q(sign):
            r = -np.asarray(sign, np.float64)
            if (r > 0).all():
                return np.array([0.0, 0.0, 0.0, 1.0])
            out = np.zeros(4)
            out[int(np.argmax(r))] = 1.0
            return out

        world = np.ones(3)
        world[self.axis] = -1
        return np.stack([q(s) for s in self.signs]), q(world)

    def rotations(self, rot: np.ndarray, parents: np.ndarray) -> np.ndarray:
        """Mirror local quaternions (..., J, 4) (x, y, z, w)."""
        a, m = self._quats()
        rot = np.asarray(rot, np.float64)
        left = np.where((parents < 0)[:, None], m, a[np.maximum(parents, 0)])
        out = quat_mul(quat_mul(np.broadcast_to(left, rot.shape), rot), np.broadcast_to(a, rot.shape))
        return out[..., self.pairs, :]

    def root(self, root: np.ndarray) -> np.ndarray:
        out = np.array(root, np.float64, copy=True)
        out[..., self.axis] *= -1
        return out

    def contacts(self, c: np.ndarray, feet: list[int]) -> np.ndarray:
        """Swap per-foot channels (..., len(feet)) to their mirror joints."""
        order = [feet.index(int(self.pairs[f])) for f in feet]
        return np.asarray(c)[..., order]


def find_pairs(names: tuple[str, ...]) -> np.ndarray:
    """Pair each joint by its name with _L/_R, Left/Right or l/r swapped (itself when none)."""
    swaps = [("_L", "_R"), ("_l", "_r"), ("Left", "Right"), ("left", "right"), ("L_", "R_"), ("l_", "r_")]
    index = {n: i for i, n in enumerate(names)}
    pairs = np.arange(len(names))
    for i, n in enumerate(names):
        for a, b in swaps:
            for x, y in ((a, b), (b, a)):
                if x in n and n.replace(x, y) in index:
                    pairs[i] = index[n.replace(x, y)]
    if not np.array_equal(pairs[pairs], np.arange(len(names))):
        raise ValueError("skeleton: left/right joint names do not pair up one to one")
    return pairs


def derive_mirror(skel: Skeleton, sample: np.ndarray, axis: int = 2, tol: float = 0.03) -> Mirror:
    """The mirror of ``skel``; ``sample`` (N, J, 4) local rotations break ties between reflections.

    Raises ValueError when the rest offsets are not left/right symmetric within ``tol`` of
    each bone's length (the rig cannot be mirrored this way).
    """
    pairs = find_pairs(skel.names)
    parents = skel.parents
    for j, p in enumerate(parents):
        if p >= 0 and parents[pairs[j]] != pairs[p]:
            raise ValueError(f"skeleton: {skel.names[j]}'s mirror joint has another parent's mirror")
    children = [skel.children(j) for j in range(len(skel))]
    mats = Rotation.from_quat(np.asarray(sample, np.float64).reshape(-1, 4)).as_matrix()
    mean = mats.reshape(-1, len(skel), 3, 3).mean(0)  # chordal means, per joint
    world = np.ones(3)
    world[axis] = -1
    signs = np.zeros((len(skel), 3))
    for j in range(len(skel)):
        fits = []
        for s in _CANDIDATES:
            ok = all(
                np.linalg.norm(s * skel.offsets[pairs[c]] - skel.offsets[c])
                <= tol * max(np.linalg.norm(skel.offsets[c]), 1.0)
                for c in children[j]
            )
            if ok:
                left = world if parents[j] < 0 else signs[parents[j]]
                # Mirrored mean pose of j against the real mean pose of its pair.
                fits.append((np.abs(left[:, None] * mean[j] * s[None, :] - mean[pairs[j]]).sum(), s))
        if not fits:
            raise ValueError(f"skeleton: {skel.names[j]}'s children are not mirror images of its pair's")
        signs[j] = min(fits, key=lambda f: f[0])[1]
    return Mirror(pairs, signs, axis)
