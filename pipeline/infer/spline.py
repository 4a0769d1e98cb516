"""The spline baseline: a cubic through the keys per channel, as a DCC's default tangents draw it.

This is the animator's real alternative to a model: key the poses, let Maya or Blender run a
curve through every channel, and look. Both default to tangents that are smooth through a key
but never overshoot it: Maya's *Auto* tangents and Blender's *Auto Clamped* Bézier handles set
each key's slope from its two neighbours and flatten it where the key is a local extremum, so
the curve stays between neighbouring key values. Of scipy's cubics, the PCHIP (Fritsch–Carlson)
Hermite cubic does the same: each key's slope is the weighted harmonic mean of the slopes to its
neighbours (zero at an extremum), so every segment stays within its two keys' values and the
curve is C1. A C2 ``CubicSpline`` is smoother but overshoots — it rings after a fast key
sequence, which no default DCC tangent does (through the bench's 10 context frames and a
target 45 frames on, its L2P is 28.5 against PCHIP's 3.0) — and Akima's slopes are not
flattened at extrema.
PCHIP reproduces straight lines exactly (with two keys it *is* the line), not cubics.

One difference remains at the ends: Blender flattens the first and last key's auto handles
(an ease in/out, with constant extrapolation); scipy's PCHIP gives them a one-sided three-point
slope instead, which keeps two keys linear. ``ends="flat"`` gives Blender's ease at the ends.
``method="cubic"`` gives a not-a-knot C2 spline, which reproduces cubic polynomials exactly.

``method="adaptive"`` is the trusted fill's curve (``pipeline.infer.trust``): where keys are
dense, clamping is wrong. A key every few frames is rarely an extreme of every channel, yet
PCHIP flattens every channel that turns there, and the motion between dense keys is smooth
enough for the unclamped Catmull-Rom slope ((y[k+1] − y[k−1]) / (x[k+1] − x[k−1]), Maya's
*Spline* tangent) to follow it. Where keys are sparse, the clamped slope is right: the motion
between them has more in it than one cubic, and an unclamped one overshoots it. So each key's
slope is Catmull-Rom's where both gaps beside it are at most :data:`DENSE_S` seconds, PCHIP's
where either is :data:`SPARSE_S` or longer, and blended linearly between; the two keys
beside a cut (``breaks``) keep PCHIP's, so a teleport does not swing the gaps next to it.
Measured ÷ PCHIP (world joint positions between the keys; ``experiments/curve_tangents.py``):
keys every 10 frames 0.95 on Bandai eval shots and 0.97 on CMU subjects 5–7's own rig, keys
placed pose to pose one per 10 frames on average 0.97, keys every 20 and 30 frames 1.00
(Catmull-Rom alone 1.03 and 1.01; not-a-knot 1.14 and 1.03); but 1.04 on motions that end
in holds (Bandai raise-up and wave takes; 1.08 without :data:`SLOPE_BOUND`). C1 and local, as PCHIP.

Channels: the root position's xyz, and each joint's local quaternion as four components made
hemisphere-consistent from key to key (q_k · q_{k-1} ≥ 0), interpolated, then renormalised.
Key frames are copied back bitwise; before the first key and after the last, keys are held.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.interpolate import CubicHermiteSpline, CubicSpline, PchipInterpolator

from pipeline.infer.api import Capabilities, refuse_extras
from pipeline.motion.clip import Motion
from pipeline.motion.skeleton import Skeleton

METHODS = ("pchip", "cubic", "adaptive")
#: ``SplineInbetweener.fill(feet=BY_NAME)``: plant on the legs the model's joint names find.
BY_NAME = "model leg joints by name"
#: ``adaptive``: a key whose neighbouring gaps are both at most this long (seconds) takes
#: Catmull-Rom's slope; from SPARSE_S (either gap) PCHIP's; linearly between. 12 and 20 frames
#: at 30 fps: Catmull-Rom is 0.93x PCHIP keyed every 10 frames, 0.97x every 15, 1.02x every 20.
DENSE_S = 0.4
SPARSE_S = 2.0 / 3.0
#: ``adaptive``: Catmull-Rom's slope at most this many times the smaller secant beside the key
#: (Fritsch and Carlson's bound for a cubic that does not overshoot). Unbounded, the curve was
#: 1.08x PCHIP on Bandai raise-up and wave takes keyed every 10 frames; bounded 1.04.
SLOPE_BOUND = 3.0


def _curve(x: np.ndarray, y: np.ndarray, method: str, ends: str, fps: float, breaks=()):
    """One scipy interpolant over all channels: ``y`` is (K, C) at key frames ``x`` (K,);
    ``breaks``: (a, b) adjacent key frames whose keys keep PCHIP's slope (``adaptive``)."""
    if method == "cubic":
        return CubicSpline(x, y, axis=0, bc_type="not-a-knot")
    pchip = PchipInterpolator(x, y, axis=0)
    if ends == "auto" and method == "pchip":
        return pchip
    slopes = pchip.derivative()(x)
    if method == "adaptive" and len(x) > 2:
        gaps = np.diff(x) / fps
        widest = np.maximum(np.r_[gaps[0], gaps], np.r_[gaps, gaps[-1]])[1:-1]
        dense = np.clip((SPARSE_S - widest) / (SPARSE_S - DENSE_S), 0.0, 1.0)[:, None]
        for a, b in breaks:  # a cut: Catmull-Rom's slope would carry its jump into the next gap
            i = np.searchsorted(x, a)
            if i + 1 < len(x) and x[i] == a and x[i + 1] == b:
                dense[[j - 1 for j in (i, i + 1) if 0 < j < len(x) - 1]] = 0.0
        catmull = (y[2:] - y[:-2]) / (x[2:] - x[:-2])[:, None]
        # Fritsch-Carlson's bound: a key next to a hold (a near-zero secant) does not carry
        # the move into it and overshoot.
        if np.isfinite(SLOPE_BOUND):  # (infinite: unbounded, for experiments/curve_tangents.py)
            secant = np.abs(np.diff(y, axis=0) / np.diff(x)[:, None])
            bound = SLOPE_BOUND * np.minimum(secant[:-1], secant[1:])
            catmull = np.clip(catmull, -bound, bound)
        slopes[1:-1] = dense * catmull + (1.0 - dense) * slopes[1:-1]
    if ends == "flat":
        slopes[[0, -1]] = 0.0
    return CubicHermiteSpline(x, y, slopes, axis=0)


def _checked_inputs(rotations, root_positions, keys, method: str, ends: str):
    """:func:`spline_keys`'s inputs as arrays, the keys sorted and unique; a ValueError for a
    bad method or ends, mismatched shapes, fewer than two keys or a key outside the motion."""
    if method not in METHODS:
        raise ValueError(f"unknown spline method {method!r} (one of {', '.join(METHODS)})")
    if ends not in ("auto", "flat"):
        raise ValueError(f"unknown spline ends {ends!r} (auto or flat)")
    rotations = np.asarray(rotations)
    root_positions = np.asarray(root_positions)
    T = rotations.shape[0]
    if rotations.shape[-1] != 4 or root_positions.shape[0] != T or root_positions.shape[-1] != 3:
        raise ValueError(f"rotations {rotations.shape} / root positions {root_positions.shape} do not match")
    keys = np.unique(np.asarray(keys, np.int64))
    if len(keys) < 2:
        raise ValueError("a spline needs at least two keys")
    if keys[0] < 0 or keys[-1] >= T:
        raise ValueError(f"keys {keys[0]}..{keys[-1]} outside the motion's {T} frames")
    return rotations, root_positions, keys


def spline_keys(
    rotations: np.ndarray,
    root_positions: np.ndarray,
    keys: np.ndarray,
    method: str = "pchip",
    ends: str = "auto",
    fps: float = 30.0,
    breaks=(),
) -> tuple[np.ndarray, np.ndarray]:
    """Every frame between the keys on the spline through them; outside the keys, held.

    ``rotations`` (T, ..., 4) unit quaternions (any joint layout, e.g. (T, J, 4) or
    (T, N, J, 4) for N clips sharing the key times), ``root_positions`` (T, ..., 3); only
    the frames in ``keys`` (int indices, at least two distinct) are read. Returns arrays of
    the same shapes and dtypes whose key frames equal the input bitwise. Between key k and
    key k+1 the output quaternions carry key k's sign, as SLERP from key k does.
    ``method``: ``"pchip"`` (DCC auto/clamped tangents), ``"cubic"`` (not-a-knot C2) or
    ``"adaptive"`` (Catmull-Rom slopes at dense keys, PCHIP's at sparse ones, by the key
    frames' rate ``fps``; ``breaks``: adjacent key frames with a cut between, kept PCHIP's);
    ``ends``: ``"auto"`` (scipy's end slopes) or ``"flat"`` (ease in/out at the first and last
    key, as Blender's auto-clamped handles; not with ``"cubic"``).
    """
    rotations, root_positions, keys = _checked_inputs(rotations, root_positions, keys, method, ends)
    q = rotations[keys].reshape(len(keys), -1, 4).astype(np.float64)  # (K, M, 4)
    # Hemisphere-consistent keys: flip c_k = c_{k-1} · sign(q_k · q_{k-1}) (0 counts as +).
    step = np.where((q[1:] * q[:-1]).sum(-1) < 0, -1.0, 1.0)
    sign = np.concatenate([np.ones((1, q.shape[1])), np.cumprod(step, axis=0)])  # (K, M)
    q *= sign[..., None]
    p = root_positions[keys].reshape(len(keys), -1).astype(np.float64)  # (K, 3R)
    m4 = q.shape[1] * 4
    y = np.concatenate([q.reshape(len(keys), m4), p], axis=1)

    frames = np.arange(keys[0], keys[-1] + 1)
    v = _curve(keys.astype(np.float64), y, method, ends, fps, breaks)(frames.astype(np.float64))  # (F, C)
    rot_f = v[:, :m4].reshape(len(frames), -1, 4)
    # The segment each frame lies in (a key frame counts in the segment it starts).
    seg = np.clip(np.searchsorted(keys, frames, side="right") - 1, 0, len(keys) - 2)
    norm = np.linalg.norm(rot_f, axis=-1, keepdims=True)
    small = norm < 1e-6
    if small.any():  # Components crossing zero together: the segment's normalised LERP instead.
        w = ((frames - keys[seg]) / (keys[seg + 1] - keys[seg]))[:, None, None]
        lerp = (1 - w) * q[seg] + w * q[seg + 1]
        rot_f = np.where(small, lerp, rot_f)
        norm = np.linalg.norm(rot_f, axis=-1, keepdims=True)
    # Back to each segment's left key's sign, as the input carried it.
    rot_f = rot_f / norm * sign[seg][..., None]

    out_dtype_r = rotations.dtype if np.issubdtype(rotations.dtype, np.floating) else np.float64
    out_dtype_p = root_positions.dtype if np.issubdtype(root_positions.dtype, np.floating) else np.float64
    rot = np.empty(rotations.shape, out_dtype_r)
    pos = np.empty(root_positions.shape, out_dtype_p)
    rot[frames] = rot_f.reshape((len(frames), *rotations.shape[1:]))
    pos[frames] = v[:, m4:].reshape((len(frames), *root_positions.shape[1:]))
    rot[: keys[0]] = rotations[keys[0]]
    pos[: keys[0]] = root_positions[keys[0]]
    rot[keys[-1] + 1 :] = rotations[keys[-1]]
    pos[keys[-1] + 1 :] = root_positions[keys[-1]]
    rot[keys] = rotations[keys]
    pos[keys] = root_positions[keys]
    return rot, pos


def spline_motion(
    motion: Motion, keys: np.ndarray, method: str = "pchip", ends: str = "auto", breaks=()
) -> Motion:
    """:func:`spline_keys` on a motion: same skeleton, frame rate and length."""
    rot, pos = spline_keys(motion.rotations, motion.root_positions, keys, method, ends, motion.fps, breaks)
    return replace(motion, rotations=rot, root_positions=pos)


class SplineInbetweener:
    """A clamped-tangent cubic through the keys per channel; on any skeleton, at any frame rate.

    ``skeleton`` only names the rig the caller means (the Bandai skeleton by default); ``fill``
    works on whatever skeleton the motion carries, at its rate (``fill_batch``: at ``fps``).
    ``method``/``ends``: as :func:`spline_keys` (``"adaptive"``: the trusted fill's curve).
    ``plant``: hold the feet the keys plant (pipeline.infer.plant; the trusted fill's curve),
    on the legs ``fill`` is given (``feet``) or the model's leg joints by name.
    """

    name = "spline"
    model_hash = "none"
    fps = 30.0
    capabilities = Capabilities(batch=True, any_rig=True)

    def __init__(
        self, skeleton: Skeleton | None = None, method: str = "pchip", ends: str = "auto", plant: bool = False
    ):
        if skeleton is None:
            from pipeline.data.skeletons import bandai_skeleton

            skeleton = bandai_skeleton()
        self.skeleton = skeleton
        self.method = method
        self.ends = ends
        self.plant = plant

    def fill(
        self,
        motion: Motion,
        keys: np.ndarray,
        seed: int = 0,
        joint_keys=None,
        dna=None,
        breaks=(),
        feet=BY_NAME,
    ) -> Motion:
        """``breaks``: (a, b) adjacent key frames with a cut between them (:func:`spline_keys`);
        ``feet``: with ``plant``, the legs to plant on (pipeline.infer.plant.Feet), None for
        none, or :data:`BY_NAME` (the model's leg joints by name, in the skeleton's space)."""
        refuse_extras(self, joint_keys, dna)
        out = spline_motion(motion, keys, self.method, self.ends, breaks)
        if not self.plant:
            return out
        from pipeline.infer.plant import model_feet, plant_feet

        feet = model_feet(motion.skeleton) if feet is BY_NAME else feet
        return out if feet is None else plant_feet(out, np.unique(keys), feet, breaks)

    def fill_batch(self, rotations: np.ndarray, roots: np.ndarray, keys: np.ndarray):
        """(N, T, J, 4) / (N, T, 3) windows sharing ``keys``, in one spline call (feet planted
        window by window)."""
        rot, pos = spline_keys(
            np.moveaxis(rotations, 1, 0), np.moveaxis(roots, 1, 0), keys, self.method, self.ends, self.fps
        )
        rot, pos = np.moveaxis(rot, 0, 1), np.moveaxis(pos, 0, 1)
        if self.plant:
            from pipeline.infer.plant import model_feet, plant_rotations

            feet = model_feet(self.skeleton)
            if feet is not None:
                k = np.unique(keys)
                rot = np.stack(
                    [plant_rotations(r, p, self.skeleton, k, feet) for r, p in zip(rot, pos, strict=True)]
                )
        return rot, pos
