"""The one interface every in-betweener implements, on the model's skeleton and frame rate."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from pipeline.motion.clip import Motion
from pipeline.motion.skeleton import Skeleton


@runtime_checkable
class Inbetweener(Protocol):
    """Fills every frame of a motion from the values at its key frames.

    ``fill(motion, keys, seed)``: ``motion`` is on :attr:`skeleton` at :attr:`fps`;
    only the frames listed in ``keys`` (sorted int indices, at least two) hold real
    values, the rest are ignored. Returns a motion of the same length whose key frames
    equal the input exactly. Frames before the first key and after the last are held.
    The same seed on the same host gives the same output.
    """

    name: str
    model_hash: str
    fps: float
    skeleton: Skeleton

    def fill(self, motion: Motion, keys: np.ndarray, seed: int = 0) -> Motion: ...


def load_inbetweener(name: str = "default") -> Inbetweener:
    """``"interp"`` (SLERP/LERP baseline), ``"spline"`` (clamped-tangent cubic through the keys)
    or ``"default"`` / a model folder (shipped ONNX model).

    ``"default"`` falls back to interpolation only when no model is shipped.
    """
    from pipeline.infer.interp import InterpolationInbetweener

    if name in ("interp", "interpolation"):
        return InterpolationInbetweener()
    if name == "spline":
        from pipeline.infer.spline import SplineInbetweener

        return SplineInbetweener()
    from pipeline.infer.model import OnnxInbetweener, find_model

    folder = find_model(name)
    if folder is None:
        if name == "default":
            return InterpolationInbetweener()
        raise FileNotFoundError(f"{name}: no such model (expected a folder with model.json)")
    return OnnxInbetweener(folder)
