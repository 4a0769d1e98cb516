"""The protocol's metrics on (N, T, J, ·) arrays of predicted and true motion."""

from __future__ import annotations

import numpy as np


def l2q(q_pred: np.ndarray, q_true: np.ndarray) -> float:
    """Mean over windows and frames of the L2 norm of the global-quaternion difference."""
    d = (q_pred - q_true).reshape(q_pred.shape[0], q_pred.shape[1], -1)
    return float(np.linalg.norm(d, axis=-1).mean())


def l2p(p_pred: np.ndarray, p_true: np.ndarray, mean: np.ndarray, std: np.ndarray) -> float:
    """Mean L2 norm of the z-scored global-position difference (63 dims per frame)."""
    n, t = p_pred.shape[:2]
    a = (p_pred.reshape(n, t, -1) - mean) / std
    b = (p_true.reshape(n, t, -1) - mean) / std
    return float(np.linalg.norm(a - b, axis=-1).mean())


def npss(q_pred: np.ndarray, q_true: np.ndarray) -> float:
    """Normalised power spectrum similarity over the predicted frames, power-weighted."""
    n, t = q_pred.shape[:2]
    pred = q_pred.reshape(n, t, -1).astype(np.float64)
    true = q_true.reshape(n, t, -1).astype(np.float64)
    p_pow = np.square(np.real(np.fft.fft(pred, axis=1)))
    t_pow = np.square(np.real(np.fft.fft(true, axis=1)))
    t_total = t_pow.sum(axis=1)  # (n, dims)
    p_total = p_pow.sum(axis=1)
    # A dimension with no power has an undefined spectrum: give it a flat one; with a true
    # power of zero it carries zero weight anyway.
    flat = np.full(t, 1.0 / t)[None, :, None]
    p_norm = np.where(p_total[:, None] > 0, p_pow / np.where(p_total > 0, p_total, 1)[:, None], flat)
    t_norm = np.where(t_total[:, None] > 0, t_pow / np.where(t_total > 0, t_total, 1)[:, None], flat)
    emd = np.abs(np.cumsum(p_norm, axis=1) - np.cumsum(t_norm, axis=1)).sum(axis=1)
    if t_total.sum() == 0:
        return float(emd.mean())
    return float(np.average(emd, weights=t_total))


def mpjpe(p_pred: np.ndarray, p_true: np.ndarray) -> float:
    """Mean per-joint position error, in the data's unit (cm)."""
    return float(np.linalg.norm(p_pred - p_true, axis=-1).mean())


def foot_skate(
    p_pred: np.ndarray,
    p_true: np.ndarray,
    prev_pred: np.ndarray,
    prev_true: np.ndarray,
    feet: list[int],
    threshold: float = 0.02,
) -> tuple[float, int]:
    """Mean horizontal foot displacement (cm/frame) on the true contact joint-frames.

    ``p_*`` (N, T, J, 3) are the predicted frames; ``prev_*`` (N, J, 3) the frame before them.
    Contact at t when the truth's squared displacement from t−1 is below ``threshold`` cm².
    Returns (skate, number of contact joint-frames).
    """
    seq_p = np.concatenate([prev_pred[:, None], p_pred], axis=1)[:, :, feet]
    seq_t = np.concatenate([prev_true[:, None], p_true], axis=1)[:, :, feet]
    d_true = np.square(np.diff(seq_t, axis=1)).sum(-1)
    contact = d_true < threshold
    d_pred = np.linalg.norm(np.diff(seq_p, axis=1)[..., [0, 2]], axis=-1)
    n = int(contact.sum())
    return (float(d_pred[contact].mean()) if n else 0.0), n
