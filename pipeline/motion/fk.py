"""Forward kinematics: local rotations + root translation -> global rotations and positions.

The numpy version serves data preparation, metrics and post-processing; the torch version
is the differentiable layer the networks train through (torch is imported lazily, so
filling a shot never imports it).
"""

from __future__ import annotations

import numpy as np

from pipeline.motion.rotations import batch_quat_normalize


def fk(
    local_rot: np.ndarray, root_pos: np.ndarray, parents, offsets, joints=None
) -> tuple[np.ndarray, np.ndarray]:
    """Global (rotations, positions) for local quaternions (..., J, 4) and root (..., 3).

    Plain float64 array arithmetic rather than a scipy ``Rotation`` per joint (whose set-up
    was most of the time on these small arrays): the local quaternions are normalised once,
    as scipy normalised them at every product, so the result equals the scipy chain to
    rounding (~1e-15); the root's global rotation is its local one as given. The work runs
    joint by joint on component rows ((J, 4, M) layout, M the frames), so each operation is
    on contiguous memory. With ``joints`` only those joints and their ancestors are
    computed; the other joints' entries are NaN.
    """
    parents = np.asarray(parents)
    offsets = np.asarray(offsets, np.float64)
    J = local_rot.shape[-2]
    root = np.asarray(root_pos, np.float64)
    lead = np.broadcast_shapes(local_rot.shape[:-2], root.shape[:-1])
    M = int(np.prod(lead, dtype=np.int64))
    todo = np.zeros(J, bool)
    for j in range(J) if joints is None else np.atleast_1d(joints):
        while j >= 0 and not todo[j]:
            todo[j] = True
            j = parents[j]
    idx = np.flatnonzero(todo)  # parents come before their children
    at = np.full(J, -1)
    at[idx] = np.arange(len(idx))
    # (n, 4, M) unit local rotations of the joints computed: one contiguous row per joint
    # and component.
    local = np.broadcast_to(local_rot, lead + local_rot.shape[-2:])
    sub = local if joints is None else local[..., idx, :]
    unit = batch_quat_normalize(sub).reshape(M, len(idx), 4).transpose(1, 2, 0)
    g_rot = np.empty((len(idx), 4, M))
    g_pos = np.empty((len(idx), 3, M))
    for i, j in enumerate(idx):
        p = at[parents[j]] if parents[j] >= 0 else -1
        if p < 0:
            g_rot[i] = unit[i]
            g_pos[i] = np.broadcast_to(root, lead + (3,)).reshape(M, 3).T
        else:
            _mul_rows(g_rot[p], unit[i], g_rot[i])
            _apply_rows(g_rot[p], offsets[j], g_pos[i])
            g_pos[i] += g_pos[p]
    # The root's own rotation as given (scipy composed, and so normalised, only the others).
    for i in np.flatnonzero(parents[idx] < 0):
        g_rot[i] = sub[..., i, :].reshape(M, 4).T
    dtype = (local_rot.dtype, np.result_type(root_pos, np.float32))
    if joints is None:
        rot = g_rot.transpose(2, 0, 1).reshape(lead + (J, 4)).astype(dtype[0])
        pos = g_pos.transpose(2, 0, 1).reshape(lead + (J, 3)).astype(dtype[1])
        return rot, pos
    rot = np.full(lead + (J, 4), np.nan, dtype[0])
    pos = np.full(lead + (J, 3), np.nan, dtype[1])
    rot[..., idx, :] = g_rot.transpose(2, 0, 1).reshape(lead + (len(idx), 4))
    pos[..., idx, :] = g_pos.transpose(2, 0, 1).reshape(lead + (len(idx), 3))
    return rot, pos


def _mul_rows(a, b, out):
    """Hamilton product of (4, M) quaternion rows into ``out`` (4, M)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    out[0] = aw * bx + bw * ax + (ay * bz - az * by)
    out[1] = aw * by + bw * ay + (az * bx - ax * bz)
    out[2] = aw * bz + bw * az + (ax * by - ay * bx)
    out[3] = aw * bw - (ax * bx + ay * by + az * bz)


def _apply_rows(q, v, out):
    """Unit quaternion rows (4, M) applied to one vector v (3,), into ``out`` (3, M)."""
    ux, uy, uz, w = q
    vx, vy, vz = v
    tx = 2 * (uy * vz - uz * vy)
    ty = 2 * (uz * vx - ux * vz)
    tz = 2 * (ux * vy - uy * vx)
    out[0] = vx + w * tx + (uy * tz - uz * ty)
    out[1] = vy + w * ty + (uz * tx - ux * tz)
    out[2] = vz + w * tz + (ux * ty - uy * tx)


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
