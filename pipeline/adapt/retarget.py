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

from pipeline.adapt.mapping import MODEL_JOINTS, MappingError
from pipeline.adapt.rig import Rig
from pipeline.data.skeletons import bandai_skeleton
from pipeline.motion.rotations import matrix_to_quat, quat_apply, quat_inv, quat_mul, quat_normalize

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


def _dir(pos: np.ndarray, a: int, b: int) -> tuple[np.ndarray, float]:
    v = pos[b] - pos[a]
    n = float(np.linalg.norm(v))
    return (v / n if n > 0 else v), n


def _arm_end(roles: dict[str, int], s: str) -> str:
    """The joint an arm's direction is measured to (the hand, or the elbow on a handless rig)."""
    return f"Hand_{s}" if f"Hand_{s}" in roles else f"LowerArm_{s}"


def humanoid_check(
    roles: dict[str, int], pos: np.ndarray, what: str = "rest pose", arms: bool = True
) -> None:
    """Raises MappingError unless ``pos`` (canonical frame) is a standing humanoid's.
    ``arms``: also ask the arms to reach sideways (a bind pose's do; in motion they swing)."""
    spine, spine_len = _dir(pos, roles["Hips"], roles["Head"])
    if spine @ UP < 0.6:
        raise MappingError(
            f"not a humanoid {what}: the spine does not point up (cos {spine @ UP:.2f}; a quadruped?)"
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
        leg, leg_len = _dir(pos, roles[f"UpperLeg_{s}"], roles[f"Foot_{s}"])
        if leg @ UP > -0.6:
            raise MappingError(f"not a humanoid {what}: leg {s} does not point down (cos {leg @ UP:.2f})")
        arm, _ = _dir(pos, roles[f"UpperArm_{s}"], roles[_arm_end(roles, s)])
        # Arms may hang in a relaxed bind pose, but they reach outwards from the shoulders
        # (a quadruped's front legs go straight down).
        if arms and sign * (arm @ left) < 0.1:
            raise MappingError(
                f"not a humanoid {what}: arm {s} does not reach sideways (points {np.round(arm, 2).tolist()})"
            )
        if not 0.5 < leg_len / max(spine_len, 1e-9) < 4.0:
            raise MappingError(
                f"not a humanoid: leg {s} is {leg_len / spine_len:.2f}x the hips-to-head length "
                "(a human's is 0.5-4x; short legs under a long body are a quadruped's)"
            )


def reference_pose(roles: dict[str, int], rot: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """Canonical reference global rotations (21, 4) for the model joints (NaN where unmapped).

    Each mapped joint's global rotation is turned so that its bone (towards the next mapped
    joint at a distance) points the canonical way, the character's forward kept forward. A
    joint without such a bone (zero length, or the last of its chain) takes its parent's
    correction."""
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
        bone = None
        for n in _NEXT.get(m, ()):
            if n in roles:
                v = pos[roles[n]] - pos[roles[m]]
                if np.linalg.norm(v) > 1e-6 * max(1.0, np.abs(pos).max()):
                    bone = v
                    break
        c = None
        if bone is not None:
            sec_rest, sec_can = (UP, UP) if m.startswith("Foot") else (fwd, FWD)
            try:
                c = _frame(_CANON[m], sec_can) @ _frame(bone, sec_rest).T
            except MappingError:
                c = None  # a bone along the secondary axis: no twist reference, inherit
        if c is None:
            p = parents[j]
            while p >= 0 and MODEL_JOINTS[p] not in corr:
                p = parents[p]
            c = corr[MODEL_JOINTS[p]] if p >= 0 else np.eye(3)
        corr[m] = c
        ref[j] = quat_mul(matrix_to_quat(c), rot[roles[m]])
    return ref


def leg_length(roles: dict[str, int], pos: np.ndarray) -> float:
    """Mean of the two legs' hip-knee-ankle bone lengths (the same in every pose)."""
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


def _fk_pos(g: np.ndarray, parents, offsets: np.ndarray) -> np.ndarray:
    """Joint positions (J, 3) of global rotations ``g`` (J, 4) on ``offsets``, root at 0."""
    pos = np.zeros((len(parents), 3))
    for j, p in enumerate(parents):
        if p >= 0:
            pos[j] = pos[p] + quat_apply(g[p], offsets[j].astype(np.float64))
    return pos


@lru_cache(maxsize=1)
def model_rest() -> np.ndarray:
    """The model skeleton's canonical T-pose, global rotations (21, 4): its stored standing
    pose brought into the reference pose. Shots converted from a rig that is the model
    skeleton are written with it as rest pose, so any tool's copy of such a rig (renamed,
    re-oriented, re-scaled) carries the model's own reference in its rest pose."""
    skel = bandai_skeleton()
    d = json.loads(Path(__file__).with_name("bandai_stand.json").read_text())["rotations_xyzw"]
    local = quat_normalize(np.array([[d[n] for n in skel.names]], np.float64))
    g = _fk_global_rot(local, skel.parents)[0]
    roles = {n: i for i, n in enumerate(skel.names)}
    return reference_pose(roles, g, _fk_pos(g, skel.parents, skel.offsets))


@lru_cache(maxsize=1)
def typical_local() -> np.ndarray:
    """The model skeleton's typical pose, local rotations (21, 4): each joint's mean over the
    train split (``bandai_mean.json``, scripts/mean_pose.py). A joint the shot's rig lacks
    takes this rotation, the one the network saw most; its reference pose's is not one the
    data knows (a T-pose clavicle is 15° from the train split's, median; a zero pose's
    identity 116°, and 90° for the Spine)."""
    skel = bandai_skeleton()
    d = json.loads(Path(__file__).with_name("bandai_mean.json").read_text())["rotations_xyzw"]
    return quat_normalize(np.array([d[n] for n in skel.names], np.float64))


@lru_cache(maxsize=1)
def model_rig() -> tuple[np.ndarray, float]:
    """The model skeleton's reference pose and leg length: the reference of its canonical
    T-pose (:func:`model_rest`), computed as a shot's rest pose is, so that a rig whose
    rest pose is that T-pose gets its own frames back exactly."""
    skel = bandai_skeleton()
    g = model_rest()
    pos = _fk_pos(g, skel.parents, skel.offsets)
    roles = {n: i for i, n in enumerate(skel.names)}
    return reference_pose(roles, g, pos), leg_length(roles, pos)


def _zero_pose_match(roles: dict[str, int], pos: np.ndarray) -> np.ndarray | None:
    """The rotation Q taking the model skeleton's zero pose (every rotation identity: bones
    along its offsets, as a BVH importer's rest) onto ``pos`` when the mapped bones agree
    within 3 degrees; else None."""
    skel = bandai_skeleton()
    zero = _fk_pos(np.tile([0.0, 0, 0, 1], (len(skel.parents), 1)), skel.parents, skel.offsets)
    a, b = [], []
    for j, m in enumerate(MODEL_JOINTS):
        p = skel.parents[j]
        if p < 0 or m not in roles or MODEL_JOINTS[p] not in roles:
            continue
        u, v = zero[j] - zero[p], pos[roles[m]] - pos[roles[MODEL_JOINTS[p]]]
        nu, nv = np.linalg.norm(u), np.linalg.norm(v)
        if nu > 1e-6 and nv > 1e-9:
            a.append(u / nu)
            b.append(v / nv)
    if len(a) < 10:
        return None
    a, b = np.array(a), np.array(b)
    u_, _, vt = np.linalg.svd(b.T @ a)
    q = u_ @ np.diag([1.0, 1.0, np.linalg.det(u_ @ vt)]) @ vt  # Kabsch: b ≈ q a
    if (np.einsum("ij,ij->i", a @ q.T, b)).min() < np.cos(np.radians(3.0)):
        return None
    return q


class Retarget:
    """Maps one character's skeleton-ordered local transforms to and from the model skeleton.

    The reference pose pair it maps through, in order of preference (``reference``):
    ``model`` (the rig's joints are the model's: the same bones in the same joint frames,
    whatever their names and rest pose: no correction at all), ``rest`` (the rest pose is a
    standing human's), ``zero pose`` (the rest pose is the model skeleton's zero pose, as a
    BVH importer writes it), ``key <t>`` (the shot's most upright key). A rig whose rest
    pose and keys are none of these is refused as not a human."""

    def __init__(
        self,
        char: Rig,
        roles: dict[str, int],
        up_axis: str,
        meters_per_unit: float,
        poses: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    ):
        """``poses``: (times (K,), rotations (K,J,4), translations (K,J,3)), skeleton-ordered
        local values of the shot's keys; they decide the reference when the rest pose
        cannot (without them only the rest pose is tried)."""
        self.char, self.roles = char, roles
        self.R, self.s, self.t = canonical_transform(char.skel_to_world, up_axis, meters_per_unit)
        self.q_R = matrix_to_quat(self.R)
        self.identity_frame = (
            np.allclose(self.R, np.eye(3), atol=1e-12) and self.s == 1.0 and not self.t.any()
        )
        model = bandai_skeleton()
        self.model_parents = model.parents
        self.missing = [m for m in MODEL_JOINTS if m not in roles]
        self.inv_roles = {v: MODEL_JOINTS.index(k) for k, v in roles.items()}
        self.direct = (
            char.names == model.names
            and np.array_equal(char.parents, model.parents)
            and np.allclose(char.rest_trans[1:] * self.s, model.offsets[1:], atol=1e-3)
        )
        self.tgt_ref, model_leg = model_rig()
        # Rest (bind) pose in the canonical frame.
        rot = quat_mul(np.broadcast_to(self.q_R, char.bind_rot.shape), char.bind_rot)
        pos = self.s * char.bind_pos @ self.R.T + self.t
        self.ratio = model_leg / leg_length(roles, pos)
        self._choose_reference(rot, pos, poses)

    def _choose_reference(self, rot: np.ndarray, pos: np.ndarray, poses) -> None:
        """The character's pose that stands for the model's reference pose, from its rest
        (bind) pose ``rot``, ``pos`` in the canonical frame: the model's own (the same rig),
        the rest pose, the zero pose, or the first standing key of ``poses``
        (``self.reference`` says which); a MappingError when none is a standing human."""
        roles = self.roles
        if self.direct:
            self.reference = "model"
            self.src_ref = self.tgt_ref
            return
        if poses is not None and self._same_frames(poses):
            self.reference, self.src_ref, self.ratio = "model", self.tgt_ref, 1.0
            return
        try:
            humanoid_check(roles, pos)
        except MappingError as e:
            why = e
        else:
            self.reference = "rest"
            self.src_ref = reference_pose(roles, rot, pos)
            return
        q = _zero_pose_match(roles, pos)
        if q is not None:
            self.reference = "zero pose"
            # The model's joint frames in its zero pose are the world's (turned by q).
            self.src_ref = np.array([rot[roles[m]] if m in roles else [np.nan] * 4 for m in MODEL_JOINTS])
            self.tgt_ref = np.tile(matrix_to_quat(q), (len(MODEL_JOINTS), 1))
            return
        if poses is not None:
            best = self._standing_key(poses)
            if best is not None:
                t, g, p = best
                self.reference = f"key {t:g}"
                self.src_ref = reference_pose(roles, g, p)
                return
        raise MappingError(f"{why}, and no key of the shot is a standing human's either")

    def _standing_key(self, poses):
        """(time, canonical global rotations, positions) of the most upright standing key."""
        times, rot, trans = poses
        g, p = self._fk(rot, trans)
        best, score = None, -np.inf
        for i in range(len(times)):
            try:
                humanoid_check(self.roles, p[i], "pose", arms=False)
            except MappingError:
                continue
            sp, _ = _dir(p[i], self.roles["Hips"], self.roles["Head"])
            legs = [-_dir(p[i], self.roles[f"UpperLeg_{s}"], self.roles[f"Foot_{s}"])[0] @ UP for s in "LR"]
            sc = sp @ UP + min(legs)
            if sc > score:
                best, score = (float(times[i]), g[i], p[i]), sc
        return best

    def _same_frames(self, poses) -> bool:
        """Whether the rig's joints carry the model's own bones in the model's own joint
        frames: every model joint maps, each below its model parent's joint, and at every key
        each model bone, seen from its parent joint's frame, is the model's offset (scaled).
        Names, rest pose, extra joints in between or beside, units and up axis may differ."""
        if self.missing:
            return False
        model = bandai_skeleton()
        parents = self.char.parents
        _, rot, trans = poses
        g, p = self._fk(rot, trans)
        for j, m in enumerate(MODEL_JOINTS):
            pj = model.parents[j]
            if pj < 0:
                continue
            i, ip = self.roles[m], self.roles[MODEL_JOINTS[pj]]
            a = parents[i]
            while a >= 0 and a != ip:
                a = parents[a]
            if a != ip:
                return False
            v = quat_apply(quat_inv(g[:, ip]), p[:, i] - p[:, ip])
            want = model.offsets[j].astype(np.float64)
            if np.abs(v - want).max() > 1e-3 + 1e-4 * np.linalg.norm(want):
                return False
        return True

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
        typical = typical_local()
        for j, m in enumerate(MODEL_JOINTS):
            par = self.model_parents[j]
            if m in self.roles:
                delta = quat_mul(quat_inv(self.src_ref[j]), self.tgt_ref[j])
                g[:, j] = quat_mul(g_src[:, self.roles[m]], np.broadcast_to(delta, (T, 4)))
            else:  # a joint the rig lacks: the typical pose; its mapped children keep their world rotations
                g[:, j] = quat_mul(g[:, par], np.broadcast_to(typical[j], (T, 4)))
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
