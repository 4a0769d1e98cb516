"""Retargeting between a shot's rig and the model skeleton through canonical reference poses.

Both rigs are brought into the same canonical frame (Y up, centimetres, facing +Z,
character's left +X) and into a canonical reference pose (spine up, arms out sideways,
legs down, feet forward) built from their own rest pose: each mapped joint's global
rotation is corrected by the rotation that takes its bone (towards the next mapped
joint) onto the canonical direction while keeping the character's forward as forward.
Per joint, G_tgt(t) = G_src(t) · G_srcRef⁻¹ · G_tgtRef, so rigs whose rest orientations,
bone lengths or units differ map correctly. A rig that *is* the model skeleton is
copied directly, so a shot converted from a Bandai BVH round-trips exactly.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import numpy as np

from pipeline.data.skeletons import bandai_skeleton
from pipeline.motion.rotations import matrix_to_quat, quat_apply, quat_inv, quat_mul, quat_normalize
from pipeline.usd.mapping import MODEL_JOINTS, MappingError

UP, LEFT, FWD = np.eye(3)[1], np.eye(3)[0], np.eye(3)[2]
# Next mapped joint along each model bone (first one present wins); absent: inherit the parent's correction.
_NEXT = {
    "Hips": ("Spine", "Chest", "Neck", "Head"), "Spine": ("Chest", "Neck", "Head"),
    "Chest": ("Neck", "Head"), "Neck": ("Head",),
    **{f"{a}_{s}": (f"{b}_{s}",) for s in "LR" for a, b in
       (("Shoulder", "UpperArm"), ("UpperArm", "LowerArm"), ("LowerArm", "Hand"),
        ("UpperLeg", "LowerLeg"), ("LowerLeg", "Foot"), ("Foot", "Toes"))},
}  # fmt: skip
_CANON = {
    "Hips": UP, "Spine": UP, "Chest": UP, "Neck": UP,
    **{f"{r}_L": LEFT for r in ("Shoulder", "UpperArm", "LowerArm")},
    **{f"{r}_R": -LEFT for r in ("Shoulder", "UpperArm", "LowerArm")},
    **{f"{r}_{s}": -UP for s in "LR" for r in ("UpperLeg", "LowerLeg")},
    "Foot_L": FWD, "Foot_R": FWD,
}  # fmt: skip


def _frame(primary: np.ndarray, secondary: np.ndarray) -> np.ndarray:
    x = primary / np.linalg.norm(primary)
    z = secondary - (secondary @ x) * x
    n = np.linalg.norm(z)
    if n < 1e-6:
        raise MappingError("degenerate rest pose: a bone is parallel to the character's forward axis")
    z = z / n
    return np.stack([x, np.cross(z, x), z], axis=1)


def canonical_transform(skel_to_world: np.ndarray, up_axis: str, meters_per_unit: float):
    """(R 3x3, s, t) with canonical = s·R·p_skel + t (Y up, centimetres)."""
    up_fix = np.eye(3) if up_axis == "Y" else np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # Z up → Y up
    m = skel_to_world[:3, :3]
    k = abs(np.linalg.det(m)) ** (1 / 3)
    if not k > 0:
        raise MappingError("the skeleton's world transform is singular")
    u, _, vt = np.linalg.svd(m / k)
    r = u @ vt
    if np.linalg.det(r) < 0:
        raise MappingError("the skeleton's world transform is mirrored")
    s_units = meters_per_unit / 0.01
    return up_fix @ r, s_units * k, s_units * (up_fix @ skel_to_world[:3, 3])


def humanoid_check(roles: dict[str, int], pos: np.ndarray) -> None:
    """Raises MappingError unless the rest pose (canonical frame) is a standing humanoid's."""

    def d(a, b):
        v = pos[roles[b]] - pos[roles[a]]
        n = np.linalg.norm(v)
        return v / n if n > 0 else v, n

    spine, spine_len = d("Hips", "Head")
    if spine @ UP < 0.6:
        raise MappingError(
            f"not a humanoid rest pose: the spine does not point up (cos {spine @ UP:.2f}; a quadruped?)"
        )
    left = (
        pos[roles["UpperLeg_L"]]
        - pos[roles["UpperLeg_R"]]
        + pos[roles["UpperArm_L"]]
        - pos[roles["UpperArm_R"]]
    )
    left -= (left @ UP) * UP
    left /= max(np.linalg.norm(left), 1e-9)
    for s, sign in (("L", 1), ("R", -1)):
        leg, leg_len = d(f"UpperLeg_{s}", f"Foot_{s}")
        if leg @ UP > -0.6:
            raise MappingError(f"not a humanoid rest pose: leg {s} does not point down (cos {leg @ UP:.2f})")
        arm, _ = d(f"UpperArm_{s}", f"Hand_{s}")
        # Arms may hang in a relaxed bind pose, but they reach outwards from the shoulders
        # (a quadruped's front legs go straight down).
        if sign * (arm @ left) < 0.1:
            raise MappingError(
                f"not a humanoid rest pose: arm {s} does not reach sideways (points {np.round(arm, 2).tolist()})"
            )
        if not 0.5 < leg_len / max(spine_len, 1e-9) < 4.0:
            raise MappingError(
                f"not a humanoid: leg {s} is {leg_len / spine_len:.2f}x the hips-to-head length "
                "(a human's is 0.5-4x; short legs under a long body are a quadruped's)"
            )


def reference_pose(roles: dict[str, int], rot: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """Canonical reference global rotations (21, 4) for the model joints (NaN where unmapped)."""
    left = np.zeros(3)
    for a in ("UpperLeg", "UpperArm"):
        left += pos[roles[f"{a}_L"]] - pos[roles[f"{a}_R"]]
    left -= (left @ UP) * UP
    left /= np.linalg.norm(left)
    fwd = np.cross(left, UP)
    ref = np.full((len(MODEL_JOINTS), 4), np.nan)
    corr: dict[str, np.ndarray] = {}
    parents = bandai_skeleton().parents
    for j, m in enumerate(MODEL_JOINTS):
        if m not in roles:
            continue
        nxt = next((n for n in _NEXT.get(m, ()) if n in roles), None)
        if nxt is None:
            p = parents[j]
            while p >= 0 and MODEL_JOINTS[p] not in corr:
                p = parents[p]
            c = corr[MODEL_JOINTS[p]] if p >= 0 else np.eye(3)
        else:
            bone = pos[roles[nxt]] - pos[roles[m]]
            canon = _CANON[m]
            sec_rest, sec_can = (UP, UP) if m.startswith("Foot") else (fwd, FWD)
            c = _frame(canon, sec_can) @ _frame(bone, sec_rest).T
        corr[m] = c
        ref[j] = quat_mul(matrix_to_quat(c), rot[roles[m]])
    return ref


def leg_length(roles: dict[str, int], pos: np.ndarray) -> float:
    total = 0.0
    for s in "LR":
        a, b, c = (pos[roles[f"{r}_{s}"]] for r in ("UpperLeg", "LowerLeg", "Foot"))
        total += np.linalg.norm(b - a) + np.linalg.norm(c - b)
    return total / 2


def _fk_global_rot(local: np.ndarray, parents) -> np.ndarray:
    g = np.empty_like(local, dtype=np.float64)
    for j, p in enumerate(parents):
        g[:, j] = local[:, j] if p < 0 else quat_mul(g[:, p], local[:, j].astype(np.float64))
    return g


@lru_cache(maxsize=1)
def model_rig() -> tuple[np.ndarray, float]:
    """The model skeleton's reference pose (from a stored standing pose) and leg length."""
    skel = bandai_skeleton()
    d = json.loads(Path(__file__).with_name("bandai_stand.json").read_text())["rotations_xyzw"]
    local = quat_normalize(np.array([[d[n] for n in skel.names]], np.float64))
    g = _fk_global_rot(local, skel.parents)[0]
    pos = np.zeros((len(skel), 3))
    for j, p in enumerate(skel.parents):
        if p >= 0:
            pos[j] = pos[p] + quat_apply(g[p], skel.offsets[j].astype(np.float64))
    roles = {n: i for i, n in enumerate(skel.names)}
    return reference_pose(roles, g, pos), leg_length(roles, pos)


class Retarget:
    """Maps one character's skeleton-ordered local transforms to and from the model skeleton."""

    def __init__(self, char, roles: dict[str, int], up_axis: str, meters_per_unit: float):
        self.char, self.roles = char, roles
        self.R, self.s, self.t = canonical_transform(char.skel_to_world, up_axis, meters_per_unit)
        self.q_R = matrix_to_quat(self.R)
        self.identity_frame = (
            np.allclose(self.R, np.eye(3), atol=1e-12) and self.s == 1.0 and not self.t.any()
        )
        model = bandai_skeleton()
        self.direct = (
            char.names == model.names
            and np.array_equal(char.parents, model.parents)
            and np.allclose(char.rest_trans[1:] * self.s, model.offsets[1:], atol=1e-3)
        )
        # Rest (bind) pose in the canonical frame.
        rot = quat_mul(np.broadcast_to(self.q_R, char.bind_rot.shape), char.bind_rot)
        pos = self.s * char.bind_pos @ self.R.T + self.t
        if not self.direct:
            humanoid_check(roles, pos)
        self.src_ref = reference_pose(roles, rot, pos)
        self.tgt_ref, model_leg = model_rig()
        self.ratio = model_leg / leg_length(roles, pos)
        self.model_parents = model.parents
        self.inv_roles = {v: MODEL_JOINTS.index(k) for k, v in roles.items()}

    # -- shot rig -> model -------------------------------------------------------------
    def _fk(self, rot: np.ndarray, trans: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        T, J = rot.shape[:2]
        g = np.empty((T, J, 4))
        p = np.empty((T, J, 3))
        for j, par in enumerate(self.char.parents):
            if par < 0:
                g[:, j] = quat_mul(np.broadcast_to(self.q_R, (T, 4)), rot[:, j].astype(np.float64))
                p[:, j] = self.s * trans[:, j] @ self.R.T + self.t
            else:
                g[:, j] = quat_mul(g[:, par], rot[:, j].astype(np.float64))
                p[:, j] = p[:, par] + self.s * quat_apply(g[:, par], trans[:, j].astype(np.float64))
        return g, p

    def to_model(self, rot: np.ndarray, trans: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Skeleton-ordered local (T,J,4)/(T,J,3) → model local rotations (T,21,4), root (T,3)."""
        if self.direct and self.identity_frame:
            return rot.astype(np.float32).copy(), trans[:, 0].astype(np.float32).copy()
        g_src, p_src = self._fk(rot, trans)
        T = rot.shape[0]
        if self.direct:
            local = rot.astype(np.float64).copy()
            local[:, 0] = g_src[:, 0]
            return local.astype(np.float32), p_src[:, 0].astype(np.float32)
        g = np.empty((T, len(MODEL_JOINTS), 4))
        local = np.empty_like(g)
        for j, m in enumerate(MODEL_JOINTS):
            par = self.model_parents[j]
            if m in self.roles:
                delta = quat_mul(quat_inv(self.src_ref[j]), self.tgt_ref[j])
                g[:, j] = quat_mul(g_src[:, self.roles[m]], np.broadcast_to(delta, (T, 4)))
            else:
                rel = quat_mul(quat_inv(self.tgt_ref[par]), self.tgt_ref[j])
                g[:, j] = quat_mul(g[:, par], np.broadcast_to(rel, (T, 4)))
            local[:, j] = g[:, j] if par < 0 else quat_mul(quat_inv(g[:, par]), g[:, j])
        root = p_src[:, self.roles["Hips"]] * self.ratio
        return local.astype(np.float32), root.astype(np.float32)

    def model_channels(self, rot_keyed: np.ndarray, trans_keyed: np.ndarray) -> np.ndarray:
        """Which model channels partial keys determine: (K, J_rig) rig joints whose rotation
        is keyed and (K,) keyed translations → (K, 22): model joints, then the root position.

        A model joint's local rotation is keyed when every rig rotation it is computed from
        is: those of the rig joints below its model parent's rig joint down to its own (from
        the rig's root for the model root). The root position takes the translations and
        the rotations above the hips. Model joints no rig joint maps to follow their parent.
        """
        parents = self.char.parents

        def chain(i: int, stop: int) -> list[int]:  # rig joints from i up to, not including, stop
            out = []
            while i >= 0 and i != stop:
                out.append(i)
                i = parents[i]
            return out

        J = len(MODEL_JOINTS)
        out = np.ones((len(rot_keyed), J + 1), bool)
        for j, m in enumerate(MODEL_JOINTS):
            par = self.model_parents[j]
            if m not in self.roles:
                out[:, j] = out[:, par] if par >= 0 else True
                continue
            up = par
            while up >= 0 and MODEL_JOINTS[up] not in self.roles:
                up = self.model_parents[up]
            stop = self.roles[MODEL_JOINTS[up]] if up >= 0 else -1
            out[:, j] = rot_keyed[:, chain(self.roles[m], stop)].all(axis=1)
        hips = self.roles["Hips"]
        out[:, J] = trans_keyed & rot_keyed[:, chain(parents[hips], -1)].all(axis=1)
        return out

    # -- model -> shot rig -------------------------------------------------------------
    def from_model(
        self, local: np.ndarray, root: np.ndarray, rot_orig: np.ndarray, trans_orig: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Model local (T,21,4)/root (T,3) → the rig's skeleton-ordered local rotations and
        translations; joints the model does not know keep ``rot_orig``/``trans_orig``."""
        rot = rot_orig.astype(np.float64).copy()
        trans = trans_orig.astype(np.float64).copy()
        T = local.shape[0]
        q_Rinv = np.broadcast_to(quat_inv(self.q_R), (T, 4))
        if self.direct:
            rot[:] = local
            rot[:, 0] = quat_mul(q_Rinv, local[:, 0].astype(np.float64))
            trans[:, 0] = ((root.astype(np.float64) - self.t) @ self.R) / self.s
            if self.identity_frame:
                rot[:, 0], trans[:, 0] = local[:, 0], root
            return rot.astype(np.float32), trans.astype(np.float32)
        g_tgt = _fk_global_rot(local.astype(np.float64), self.model_parents)
        J = len(self.char.parents)
        g = np.empty((T, J, 4))
        p = np.empty((T, J, 3))
        hips = self.roles["Hips"]
        for i, par in enumerate(self.char.parents):
            g_par = np.broadcast_to(self.q_R, (T, 4)) if par < 0 else g[:, par]
            p_par = np.broadcast_to(self.t, (T, 3)) if par < 0 else p[:, par]
            if i in self.inv_roles:
                j = self.inv_roles[i]
                delta = quat_mul(quat_inv(self.tgt_ref[j]), self.src_ref[j])
                g[:, i] = quat_mul(g_tgt[:, j], np.broadcast_to(delta, (T, 4)))
                rot[:, i] = quat_mul(quat_inv(g_par), g[:, i])
            else:
                g[:, i] = quat_mul(g_par, rot[:, i])
            if i == hips:
                want = root.astype(np.float64) / self.ratio
                trans[:, i] = quat_apply(quat_inv(g_par), want - p_par) / self.s
            p[:, i] = p_par + self.s * quat_apply(g_par, trans[:, i])
        return rot.astype(np.float32), trans.astype(np.float32)
