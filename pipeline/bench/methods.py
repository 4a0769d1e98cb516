"""In-betweening methods as the benchmark sees them: context + target in, transition out.

A method is any callable ``(ctx_rot, ctx_root, tgt_rot, tgt_root, T) -> (rot, root)`` with
ctx_* of shape (N, 10, J, 4) / (N, 10, 3), tgt_* (N, J, 4) / (N, 3), returning the T
predicted frames (N, T, J, 4) / (N, T, 3) of local rotations and root positions.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from pipeline.errors import TweenError
from pipeline.infer.api import fill_windows
from pipeline.infer.interp import interpolate_between
from pipeline.infer.spline import spline_keys

Method = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int], tuple[np.ndarray, np.ndarray]]


def zero_velocity(ctx_rot, ctx_root, tgt_rot, tgt_root, T):
    """Every predicted frame repeats the last context frame."""
    rot = np.repeat(ctx_rot[:, -1:], T, axis=1)
    root = np.repeat(ctx_root[:, -1:], T, axis=1)
    return rot, root


def interpolation(ctx_rot, ctx_root, tgt_rot, tgt_root, T):
    """Root LERP and local-quaternion SLERP between the last context frame and the target."""
    rot, root = interpolate_between(ctx_rot[:, -1], tgt_rot, ctx_root[:, -1], tgt_root, T)
    return np.moveaxis(rot, 0, 1).astype(np.float32), np.moveaxis(root, 0, 1).astype(np.float32)


def spline(ctx_rot, ctx_root, tgt_rot, tgt_root, T):
    """A clamped-tangent (PCHIP) cubic per channel through every context frame and the target.

    What an animator's curves through those keys show in a DCC (``pipeline.infer.spline``).
    """
    n, c = ctx_rot.shape[:2]
    rots = np.concatenate([ctx_rot, np.zeros((n, T, *ctx_rot.shape[2:]), ctx_rot.dtype), tgt_rot[:, None]], 1)
    roots = np.concatenate([ctx_root, np.zeros((n, T, 3), ctx_root.dtype), tgt_root[:, None]], 1)
    keys = np.r_[np.arange(c), c + T]
    rot, root = spline_keys(np.moveaxis(rots, 1, 0), np.moveaxis(roots, 1, 0), keys)
    rot = np.moveaxis(rot, 0, 1)[:, c : c + T]
    root = np.moveaxis(root, 0, 1)[:, c : c + T]
    return rot.astype(np.float32), root.astype(np.float32)


def inbetweener_method(inbetweener, batch: int = 64) -> Method:
    """Adapts a product :class:`~pipeline.infer.api.Inbetweener` (keys = context + target):
    in batches through ``fill_batch`` when it declares ``capabilities.batch``, else clip by clip."""

    def run(ctx_rot, ctx_root, tgt_rot, tgt_root, T):
        n, c = ctx_rot.shape[:2]
        L = c + T + 1
        rots = np.concatenate([ctx_rot, np.repeat(tgt_rot[:, None], T + 1, axis=1)], axis=1)
        roots = np.concatenate([ctx_root, np.repeat(tgt_root[:, None], T + 1, axis=1)], axis=1)
        keys = np.r_[np.arange(c), L - 1]
        r, p = fill_windows(inbetweener, rots, roots, keys, batch, fps=30.0)
        return r[:, c : c + T], p[:, c : c + T]

    return run


BASELINES: dict[str, Method] = {"zero": zero_velocity, "interp": interpolation, "spline": spline}


def check_methods(names: list[str]) -> None:
    """Raises TweenError (one line naming ``--methods``) unless every name can be resolved:
    a baseline, ``model``, a folderless kind, or a human model's folder (a per-rig model's
    rig.json folder is refused: its network takes its own rig's joints, not the eval motion)."""
    from pipeline.infer.api import RIG_FILE, builtin_names, model_folder

    if not names:
        raise TweenError("--methods: give at least one method")
    for name in names:
        if name in BASELINES or name == "model" or name in builtin_names():
            continue
        found = model_folder(name)
        if not found:
            raise TweenError(
                f"--methods {name!r}: not {', '.join(BASELINES)}, model, or a model folder (model.json)"
            )
        if found[1] == RIG_FILE:
            raise TweenError(
                f"--methods {name!r}: {found[0]} is a per-rig model (rig.json), trained on its own rig; "
                "the bench runs human models (a folder with model.json) on the human eval motion"
            )


def resolve(name: str) -> Method:
    if name in BASELINES:
        return BASELINES[name]
    from pipeline.infer.api import load_model

    return inbetweener_method(load_model("default" if name == "model" else name))
