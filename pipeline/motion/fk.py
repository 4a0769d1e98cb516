"""Forward kinematics: local rotations + root translation -> global rotations and positions.

The numpy version serves data preparation, metrics and post-processing; the torch version
is the differentiable layer the networks train through (torch is imported lazily, so
filling a shot never imports it).
"""

from __future__ import annotations

import numpy as np

from pipeline.motion.rotations import quat_apply, quat_mul


def fk(local_rot: np.ndarray, root_pos: np.ndarray, parents, offsets) -> tuple[np.ndarray, np.ndarray]:
    """Global (rotations, positions) for local quaternions (..., J, 4) and root (..., 3)."""
    parents = np.asarray(parents)
    offsets = np.asarray(offsets, np.float64)
    J = local_rot.shape[-2]
    g_rot = [None] * J
    g_pos = [None] * J
    for j in range(J):
        p = parents[j]
        if p < 0:
            g_rot[j] = local_rot[..., j, :].astype(np.float64)
            g_pos[j] = np.asarray(root_pos, np.float64)
        else:
            g_rot[j] = quat_mul(g_rot[p], local_rot[..., j, :].astype(np.float64))
            g_pos[j] = g_pos[p] + quat_apply(g_rot[p], offsets[j])
    rot = np.stack(g_rot, axis=-2)
    pos = np.stack(g_pos, axis=-2)
    return rot.astype(local_rot.dtype, copy=False), pos.astype(
        np.result_type(root_pos, np.float32), copy=False
    )


def fk_torch(local_rot, root_pos, parents, offsets):
    """Differentiable FK: local unit quaternions (..., J, 4) xyzw, root (..., 3) -> (rot, pos).

    Uses roma's quaternion product and action (xyzw, like the rest of the project).
    """
    import roma
    import torch

    offsets = torch.as_tensor(np.asarray(offsets), dtype=local_rot.dtype, device=local_rot.device)
    g_rot, g_pos = [], []
    for j, p in enumerate(np.asarray(parents).tolist()):
        q = local_rot[..., j, :]
        if p < 0:
            g_rot.append(q)
            g_pos.append(root_pos)
        else:
            g_rot.append(roma.quat_product(g_rot[p], q))
            off = offsets[j].expand(q.shape[:-1] + (3,))
            g_pos.append(g_pos[p] + roma.quat_action(g_rot[p], off, is_normalized=True))
    return torch.stack(g_rot, dim=-2), torch.stack(g_pos, dim=-2)
