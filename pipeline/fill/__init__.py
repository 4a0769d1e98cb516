"""Filling shots: the orchestration above USD I/O, rig adaptation and the in-betweeners.

``api`` is what the farm and ``tween fill-local`` call (validate, fill takes, write
layers); ``plan`` checks a shot and picks each character's model and retargeter; ``solve``
fills one character; ``reference`` turns a reference take into model-skeleton motion;
``cli`` holds the in-process commands (``convert``, ``fill-local``, ``approve``, ``publish``).
"""

from pipeline.fill.api import FillOptions, fill_shot, fill_take, load_take, validate_shot, write_layers

__all__ = ["FillOptions", "fill_shot", "fill_take", "load_take", "validate_shot", "write_layers"]
