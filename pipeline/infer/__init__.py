"""Inference: the in-betweener interface, the interpolation baseline and the shipped model.

Nothing here imports torch: the farm fills shots with onnxruntime and numpy only.
"""

from pipeline.infer.api import Inbetweener, load_inbetweener

__all__ = ["Inbetweener", "load_inbetweener"]
