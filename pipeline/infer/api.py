"""The one interface every in-betweener implements, on the model's skeleton and frame rate."""

from __future__ import annotations

from pathlib import Path
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
    from pipeline.infer.model import OnnxInbetweener, find_model, read_model_json

    folder = find_model(name)
    if folder is None:
        broken = _folder_without_json(name)
        if broken is not None:  # its ONNX files are there, model.json is not: a broken model
            read_model_json(broken)  # ModelFolderError: "<folder>/model.json: missing (...)"
        if name == "default":
            return InterpolationInbetweener()
        raise FileNotFoundError(f"{name}: no such model (expected a folder with model.json)")
    return OnnxInbetweener(folder)


def _folder_without_json(name: str):
    """The model folder ``name`` refers to when it holds .onnx files but no model.json (and is
    no per-rig model, which has rig.json instead), else None."""
    from pipeline.infer.model import models_root

    for cand in (Path(name), models_root() / name):
        try:
            if cand.is_dir() and not (cand / "rig.json").exists() and any(cand.glob("*.onnx")):
                return cand
        except OSError:
            continue
    return None
