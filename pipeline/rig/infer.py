"""A per-rig GANimator on onnxruntime + numpy: filling blocked shots and free synthesis.

No torch here. Filling (see docs/rig.md):

1. the keys are interpolated (SLERP/LERP) and encoded; downsampled to the coarsest level
   they *are* the coarsest motion (the paper's key-frame editing: G1's output replaced);
2. every finer level upsamples, adds channel-shared noise at the level's amplitude (the
   variation between takes) and runs its generator; then the root-displacement channels
   are replaced by the keys' trajectory (the paper's concatenation trick, constrained
   joints = the root) and the frames at the keys are pulled back to the keys with a
   smoothstep-spread residual, so the finer levels add detail around the keys rather than
   drifting from them;
3. the same post-processing as the human model: ``match_keys`` (keys exact, corrections
   spread) and ``lock_feet`` (two-bone IK on the predicted contacts).
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from pipeline import jsonfile
from pipeline.errors import TweenError
from pipeline.infer.api import Capabilities, refuse_extras
from pipeline.infer.folder import JSON_LIMIT, check_hash, check_onnx_file, files_hash
from pipeline.infer.interp import interpolate_keys
from pipeline.infer.post import lock_feet, match_keys
from pipeline.inputs import FPS_MAX, broken_link, frame_rate_trouble, not_a_file, read_small_text
from pipeline.motion.clip import Motion
from pipeline.motion.rotations import quat_continuity
from pipeline.motion.skeleton import Skeleton
from pipeline.rig.represent import RigSpec, encode, from_yup, resample_linear, to_yup

MIN_FRAMES = 8  # spans shorter than this are interpolated (every level needs > 2 frames)
#: The kinds of this family in rig.json: the name, and the spelling of earlier rig.json files.
KINDS = ("rig-ganimator-onnx", "rig")
#: The most frames a level's ``train_length`` may say (756 at the elephant's finest): a fill
#: of n frames runs its coarse levels at n times their length over the last's.
MAX_TRAIN_LENGTH = 1_000_000


class RigModelError(TweenError):
    """A rig model folder is missing or unreadable: one line naming the folder."""

    def __init__(self, folder, message: str):
        super().__init__(f"{folder}: {message}")


def _smoothstep(x):
    return x * x * (3 - 2 * x)


def spread_residual(x: np.ndarray, idx: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``x`` (C, L) plus a correction that makes columns ``idx`` equal ``target`` (C, K),
    interpolated with smoothstep weights between neighbouring keys and held outside."""
    L = x.shape[-1]
    idx = np.asarray(idx)
    res = target - x[:, idx]
    t = np.arange(L)
    nxt = np.clip(np.searchsorted(idx, t, side="left"), 0, len(idx) - 1)
    prv = np.clip(nxt - 1, 0, len(idx) - 1)
    prv = np.where(idx[nxt] == t, nxt, prv)
    span = np.maximum(idx[nxt] - idx[prv], 1)
    w = np.where(idx[nxt] > idx[prv], _smoothstep(np.clip((t - idx[prv]) / span, 0, 1)), 0.0)
    w = np.where(t >= idx[-1], 1.0, w)
    prv = np.where(t >= idx[-1], len(idx) - 1, prv)
    nxt = np.where(t >= idx[-1], len(idx) - 1, nxt)
    corr = res[:, prv] * (1 - w) + res[:, nxt] * w
    out = x + corr.astype(x.dtype)
    out[:, idx] = target
    return out


class RigInbetweener:
    """Satisfies :class:`pipeline.infer.api.Inbetweener` for the rig in ``folder``/rig.json
    (kind ``"rig-ganimator-onnx"``): on that rig's skeleton only, full keys, no DNA."""

    capabilities = Capabilities()

    def __init__(self, folder: str | Path, coarse: str = "keys", feet: bool = True):
        self.folder = Path(folder)
        path = self.folder / "rig.json"
        if odd := broken_link(path):  # a link loop is no "no rig.json"
            raise RigModelError(path, odd)
        if not path.is_file():
            raise RigModelError(self.folder, "no rig.json (not a rig model folder)")
        try:
            self.meta = jsonfile.loads(read_small_text(path, JSON_LIMIT, "rig.json"))
        except (OSError, ValueError) as e:  # ValueError: not JSON (UTF-8), nested too deeply
            raise RigModelError(path, f"unreadable: {e}") from None
        kind = self.meta.get("kind") if isinstance(self.meta, dict) else None
        if kind not in KINDS:
            raise RigModelError(path, f"kind is {kind!r}, not {KINDS[0]!r}")
        try:
            self._read_meta(self.meta)
        except (KeyError, TypeError, ValueError, IndexError) as e:
            said = str(e.args[0]) if e.args else str(e)
            what = f"missing {e}" if isinstance(e, KeyError) and " " not in said else said
            raise RigModelError(path, f"not a rig model: {what}") from None
        for f in self.files:
            if not os.path.lexists(self.folder / f):
                raise RigModelError(self.folder, f"missing {f} (listed in rig.json)")
            if odd := not_a_file(self.folder / f, "level's ONNX file"):  # a device is not "missing"
                raise RigModelError(self.folder / f, f"{odd} (listed in rig.json)")
            check_onnx_file(self.folder / f)  # whole: not onnxruntime's error on the first fill
        check_hash(path, self.model_hash, files_hash(self.folder, self.files))
        self.coarse = coarse
        self.feet = feet
        self._sessions: dict[int, object] = {}

    def _read_meta(self, m: dict) -> None:
        """The rig, its representation and its levels from rig.json; ValueError (or a
        KeyError, TypeError) where a value is missing or not one a fill can use."""
        s = m["skeleton"]
        self.name = m["name"]
        self.model_hash = m["hash"]
        self.fps = float(m["fps"])
        self.skeleton = Skeleton(
            tuple(s["names"]),
            np.array(s["parents"]),
            np.array(s["offsets"], np.float32),
            s["up_axis"],
            float(s["meters_per_unit"]),
        )
        rep = m["representation"]
        self.spec = RigSpec(
            self.skeleton,
            [self.skeleton.index(n) for n in m["contact_joints"]],
            float(rep["scale"]),
            self.fps,
            float(rep["floor"]),
        )
        self.ik = [self.skeleton.index(n) for n in m.get("ik_joints", [])]
        self.train_lengths = [int(lv["train_length"]) for lv in m["levels"]]
        self.amps = [float(lv["noise_amplitude"]) for lv in m["levels"]]
        self.files = [lv["file"] for lv in m["levels"]]
        if not (np.isfinite(self.spec.scale) and self.spec.scale > 0 and np.isfinite(float(rep["floor"]))):
            raise ValueError("representation scale must be a positive number and floor finite")
        if frame_rate_trouble(m["fps"]):  # (0 divided by zero; 1e308 overflowed)
            raise ValueError(
                f"fps {self.fps!r} is not a positive number of at most {FPS_MAX:,} frames a second"
            )
        if not self.files:
            raise ValueError("no levels")
        if not all(n > 0 for n in self.train_lengths) or not all(np.isfinite(a) for a in self.amps):
            raise ValueError("a level's train_length or noise_amplitude is not a usable number")
        if max(self.train_lengths) > min(self.train_lengths[-1], MAX_TRAIN_LENGTH):
            # a fill's coarse levels are as many times its length as theirs are the last's
            raise ValueError(
                f"a level's train_length is over {MAX_TRAIN_LENGTH:,} frames or the last level's "
                f"({self.train_lengths})"
            )

    # -- the networks ------------------------------------------------------------------
    def _session(self, i: int):
        if i not in self._sessions:
            from pipeline.infer.generator_onnx import ort_session, ort_threads

            path = self.folder / self.files[i]
            ort_threads()  # the setting's own error, not the model file's
            try:
                sess = ort_session(path)
            except Exception as e:  # onnxruntime's own errors: a file it cannot load
                raise RigModelError(path, f"onnxruntime cannot load it: {str(e).splitlines()[0]}") from None
            dims = {x.name: x.shape for x in sess.get_inputs()}
            up = dims.get("up")
            width = self.spec.channels
            if "z" not in dims or up is None or (len(up) == 3 and isinstance(up[1], int) and up[1] != width):
                raise RigModelError(
                    path, f"not this rig's level {i} (inputs {dims}; up of {width} channels, and z)"
                )
            self._sessions[i] = sess
        return self._sessions[i]

    def level(self, i: int, up: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Generator i on ``up`` (F0, L) with noise ``z`` (L,) → (F0, L)."""
        out = self._session(i).run(
            ["out"], {"up": up[None].astype(np.float32), "z": z[None, None].astype(np.float32)}
        )[0]
        return out[0]

    def lengths(self, n: int) -> list[int]:
        """Level lengths for n frames: every level keeps its trained frame rate."""
        T = self.train_lengths[-1]
        out = [max(3, int(round(n * L / T))) for L in self.train_lengths[:-1]] + [n]
        return out

    @property
    def channels(self) -> int:
        return self.spec.channels

    # -- decoding ------------------------------------------------------------------------
    def _decode(self, feat: np.ndarray, begin: np.ndarray, skeleton: Skeleton):
        """Features (F0, T) → rot (T, J, 4), root (T, 3) in the Y-up frame, contacts (T, C)."""
        from pipeline.motion.rotations import matrix_to_quat, sixd_to_matrix

        T = feat.shape[-1]
        J, C = len(skeleton), len(self.spec.contacts)
        f = np.asarray(feat, np.float64).T.reshape(T, self.spec.n_vertices, 6)
        rot = matrix_to_quat(sixd_to_matrix(f[:, :J]))
        root = np.empty((T, 3))
        root[:, 1] = f[:, -1, 1] * self.spec.scale
        for a in (0, 2):
            steps = f[:, -1, a] * self.spec.scale
            steps[0] = 0.0
            root[:, a] = begin[a] + np.cumsum(steps)
        return rot, root, np.clip(f[:, J : J + C, 0], 0.0, 1.0)

    def _post_feet(self, rot_y, root_y, contacts, keys, skeleton):
        """lock_feet in the Y-up frame on the IK-able contact joints."""
        if not (self.feet and self.ik):
            return rot_y
        legs = [tuple(self.spec.legs[self.spec.contacts.index(j)]) for j in self.ik]
        cols = [self.spec.contacts.index(j) for j in self.ik]
        return lock_feet(rot_y, root_y, skeleton, contacts[:, cols], keys, legs)

    # -- the Inbetweener interface --------------------------------------------------------
    def check_motion(self, motion: Motion) -> None:
        sk = motion.skeleton
        if sk.names != self.skeleton.names or not np.array_equal(sk.parents, self.skeleton.parents):
            raise TweenError(
                f"rig model {self.name}: the motion's skeleton ({len(sk)} joints) is not this rig's "
                f"({len(self.skeleton)} joints: {', '.join(self.skeleton.names[:4])}, …)"
            )
        if abs(motion.fps - self.fps) > 1e-3:
            raise TweenError(
                f"rig model {self.name}: motion at {motion.fps:g} fps, the model runs at {self.fps:g}"
            )

    def fill(self, motion: Motion, keys: np.ndarray, seed: int = 0, joint_keys=None, dna=None) -> Motion:
        """Every frame between the keys generated; key frames exact, outside the keys held."""
        refuse_extras(self, joint_keys, dna)
        self.check_motion(motion)
        keys = np.unique(np.asarray(keys, np.int64))
        if len(keys) < 2:
            raise ValueError("fill needs at least two keys")
        if keys[0] < 0 or keys[-1] >= len(motion):
            raise ValueError(f"keys {keys[0]}..{keys[-1]} outside the motion's {len(motion)} frames")
        a, b = int(keys[0]), int(keys[-1])
        n = b - a + 1
        if n < MIN_FRAMES:  # too short for the convolutions' reflect padding: nothing to generate
            return interpolate_keys(motion, keys)
        kl = keys - a
        sk = motion.skeleton
        spec = replace(self.spec, skeleton=sk)
        base = interpolate_keys(motion, keys).slice(a, b + 1)
        guide, begin = encode(base, spec)  # (F0, n): the keys' interpolation, Y-up
        q = self._generate(guide, kl, n, spec, np.random.default_rng(seed))
        rot_y, root_y, contacts = self._decode(q, begin, sk)
        rot_y = quat_continuity(rot_y, axis=0)
        rot, root = from_yup(rot_y, root_y, sk)
        # Keys exact (bitwise) with the corrections spread between them.
        key_rot = motion.rotations[keys][None]
        key_root = motion.root_positions[keys][None]
        rot, root = match_keys(rot[None], root[None], key_rot, key_root, kl)
        rot, root = rot[0], root[0]
        if self.feet and self.ik:
            m = Motion(sk, rot, root, motion.fps)
            ry, py = to_yup(m)
            ry = self._post_feet(ry, py, contacts, kl, sk)
            rb, _ = from_yup(ry, py, sk)
            rb[:, 0] = rot[:, 0]  # the IK never turns the root; skip the Y-up round trip
            rot = rb.astype(np.float32)
        out_rot = motion.rotations.copy()
        out_root = motion.root_positions.copy()
        out_rot[a : b + 1] = rot
        out_root[a : b + 1] = root
        out_rot[:a] = motion.rotations[a]
        out_root[:a] = motion.root_positions[a]
        out_rot[b + 1 :] = motion.rotations[b]
        out_root[b + 1 :] = motion.root_positions[b]
        out_rot[keys] = motion.rotations[keys]
        out_root[keys] = motion.root_positions[keys]
        self.last_contacts = contacts
        return Motion(sk, out_rot, out_root, motion.fps, motion.name)

    def _generate(self, guide: np.ndarray, kl: np.ndarray, n: int, spec, rng) -> np.ndarray:
        """The levels run coarse to fine over the keys' interpolation ``guide`` (F0, n), each
        drawn towards the keys (frame indices ``kl``); returns the finest level's motion."""
        lens = self.lengths(n)
        R = slice(6 * (spec.n_vertices - 1), 6 * spec.n_vertices)
        q = None
        for i, L in enumerate(lens):
            g = resample_linear(guide, L)
            idx = np.clip(np.round((kl + 0.5) * L / n - 0.5).astype(np.int64), 0, L - 1)
            idx = np.unique(idx)
            if i == 0:
                if self.coarse == "keys":
                    q = g  # key-frame editing: the coarsest motion is the keys'
                    continue
                z = rng.standard_normal(L) * self.amps[0]
                q = self.level(0, np.zeros_like(g), z)
            else:
                up = resample_linear(q, L)
                z = rng.standard_normal(L) * self.amps[i]
                q = self.level(i, up, z)
            q[R] = g[R]  # concatenation trick: the root displacement follows the keys
            q = spread_residual(q, idx, g[:, idx])
        return q

    def synthesize(self, n_frames: int, seed: int = 0) -> Motion:
        """A new motion of ``n_frames`` frames: noise at the coarsest level only (as the
        official code samples), starting at the training clip's first root position."""
        n = int(n_frames)
        if n < MIN_FRAMES:
            raise ValueError(f"synthesize needs at least {MIN_FRAMES} frames")
        lens = self.lengths(n)
        rng = np.random.default_rng(seed)
        q = None
        for i, L in enumerate(lens):
            if i == 0:
                q = self.level(
                    0, np.zeros((self.channels, L), np.float32), rng.standard_normal(L) * self.amps[0]
                )
            else:
                q = self.level(i, resample_linear(q, L), np.zeros(L, np.float32))
        begin = np.array(self.meta["representation"]["begin"], np.float64)
        rot_y, root_y, contacts = self._decode(q, begin, self.skeleton)
        rot_y = quat_continuity(rot_y, axis=0)
        far = np.array([-(10**6)])  # no keys: nothing to fade the IK out at
        rot_y = self._post_feet(rot_y, root_y, contacts, far, self.skeleton)
        rot, root = from_yup(rot_y, root_y, self.skeleton)
        self.last_contacts = contacts
        return Motion(
            self.skeleton, rot.astype(np.float32), root.astype(np.float32), self.fps, f"{self.name}-{seed}"
        )
