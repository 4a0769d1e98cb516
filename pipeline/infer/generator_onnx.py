"""The shipped in-betweener on onnxruntime: generator + path predictor + post-processing.

No torch here. Sessions are created lazily, once per process (after a Celery fork).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from pipeline.data import posebank
from pipeline.data.skeletons import LEGS, bandai_skeleton
from pipeline.infer.api import Capabilities
from pipeline.infer.dna_poses import dna_poses, n_dna_channels
from pipeline.infer.features import (
    NOISE_CHANNELS,
    ROOT_SCALE,
    AdapterFreeSession,
    adapter_free_graph,
    build_features,
    check_joint_keys,
    feature_options,
    invert_transform,
    n_input_channels,
)
from pipeline.infer.folder import (  # noqa: F401  (the model folder's API, where callers find it)
    ModelFolderError,
    beside_models,
    check_hash,
    check_onnx_file,
    check_pose_bank,
    find_model,
    model_hash,
    models_root,
    ort_threads,
    read_model_json,
    shipped_library,
)
from pipeline.infer.post import lock_feet, match_keys
from pipeline.motion.clip import Motion
from pipeline.motion.rotations import batch_sixd_to_quat, slerp_pairs

# Fills up to CHUNK_FRAMES model frames (4.5 min at 30 fps) run as one window, exactly as
# they always did; longer ones go through windows of about CHUNK_CORE frames each (plus the
# network's receptive field on both sides), so that a fill's memory is bounded by the window
# and not by the shot (OnnxInbetweener.chunk_plan).
CHUNK_FRAMES = 8192
CHUNK_CORE = 2048


def ort_session(path: str | Path):
    """An onnxruntime CPU session with the farm's thread policy: ``TWEEN_ORT_THREADS`` intra-op
    threads (default 1, as workers already run one fill per core), one inter-op thread; all
    graph optimisations (onnxruntime's default, the fastest: ``tween bench --speed``).
    ``path``: a file, or a graph's bytes."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = ort_threads()
    opts.inter_op_num_threads = 1
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    graph = path if isinstance(path, bytes) else str(path)
    return ort.InferenceSession(graph, opts, providers=["CPUExecutionProvider"])


def take_latent(seed: int) -> np.ndarray:
    """The take's latent: zeros for seed 0 (the model's most likely motion), N(0, 1) otherwise."""
    if seed == 0:
        return np.zeros(NOISE_CHANNELS)
    return np.random.default_rng(seed).normal(size=NOISE_CHANNELS)


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-x))


class OnnxInbetweener:
    """Fills shots with the exported generator of a model folder, set up from its
    ``model.json`` alone.

    Kind ``"generator-onnx"``. Every such model takes partial keys and batches; it takes a
    motion DNA when its generator has a DNA encoder (``generator.dna`` in model.json), so
    ``capabilities.dna`` is set per model folder, and so is ``capabilities.novelty`` (a pose
    bank named in model.json)."""

    #: Probed beside its shipped library and networks (model.json "library", "beside"): a
    #: shot keeps this network where its keys are as familiar as its training data, and where
    #: no alternative's probes beat the spline and this network's by 0.25 (chosen on a tuning
    #: split: experiments/library_margin.py, docs/models.md; pipeline.infer.trust.probes_beside,
    #: pick). Probed beside another, it must beat that one's margin in turn.
    capabilities = Capabilities(partial_keys=True, batch=True, probe_margin=0.25, keeps_own=True)
    #: Lock the feet where the network says they touch the ground (post.lock_feet); tests
    #: that compare the network's own output turn it off.
    feet = True

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        self.meta = read_model_json(self.folder)
        dna = bool(self.meta.get("generator", {}).get("dna", 0))
        self.capabilities = replace(
            type(self).capabilities,
            dna=dna,
            novelty=bool(self.meta.get("pose_bank")),
            familiar_credit=self.meta.get("familiar_credit", True),
        )
        for name in self.meta["files"].values():
            check_onnx_file(self.folder / name)
        check_hash(self.folder / "model.json", self.meta["hash"], model_hash(self.folder, self.meta))
        self.name = self.meta["name"]
        self.model_hash = self.meta["hash"]
        self.fps = float(self.meta["fps"])
        self.skeleton = bandai_skeleton()
        # Contacts that hold a key lock at the key's ankle position; locked feet also hold
        # their orientation, so the toes do not slide (post.lock_feet).
        self.feet_anchor = bool(self.meta.get("feet_anchor", False))
        self.feet_orient = bool(self.meta.get("feet_orient", False))
        # Padded window: at least ``min_window`` frames, with at least ``pad_tail`` held frames
        # after the last key (_network).
        self.pad_tail = int(self.meta.get("pad_tail", 0))
        self.min_window = int(self.meta.get("min_window", 0))
        self.max_gap = int(self.meta.get("max_gap", 90))  # the longest gap seen in training
        # Long fills: windows of ``chunk_core`` frames, each seeing ``margin`` frames more on
        # both sides (the network's receptive field), once the fill is over ``chunk_frames``.
        self.chunk_frames, self.chunk_core = CHUNK_FRAMES, CHUNK_CORE
        self.margin = int(self.meta.get("receptive_field", 512))
        self._sessions: dict[str, object] = {}
        self._pose_bank = self._load_pose_bank()
        self.legs = [tuple(self.skeleton.index(n) for n in leg) for leg in LEGS]
        #: The motion library shipped beside the network (None: none), probed beside it.
        self.library_folder = shipped_library(self.folder, self.meta)
        #: The models shipped beside it (model.json's ``"beside"``), probed after the library.
        self.beside_folders = beside_models(self.folder, self.meta)

    #: Fills without partial keys run the generator without its partial-key adapter (the
    #: same output, 0.30 MFLOP a frame less: features.adapter_free_graph); False: always the
    #: whole graph.
    skip_adapter = True

    def _adapter_free_graph(self) -> bytes | None:
        if not self.meta.get("generator", {}).get("key_adapter", False):
            return None
        path = self.folder / self.meta["files"]["generator"]
        return adapter_free_graph(path, len(self.skeleton), 2 * int(self.meta["multiple"]))

    def session(self, which: str):
        if which not in self._sessions:
            path = self.folder / self.meta["files"][which]
            ort_threads()  # the setting's own error, not the model file's
            try:
                sess = ort_session(path)
            except Exception as e:  # onnxruntime's errors are RuntimeError subclasses of its own
                first = next((ln.strip() for ln in str(e).splitlines() if ln.strip()), type(e).__name__)
                raise ModelFolderError(f"{path}: onnxruntime cannot load it: {first}") from None
            want = {"generator": "features", "path": "local_positions"}.get(which)
            names = [i.name for i in sess.get_inputs()]
            if want and want not in names:
                raise ModelFolderError(
                    f"{path}: not this model's {which} (inputs {names}, expected {want!r})"
                )
            if which == "generator":
                self._check_channels(path, sess)
            graph = self.skip_adapter and which == "generator" and self._adapter_free_graph()
            if graph:  # fills without partial keys skip the adapter (features.adapter_free_graph)
                width = n_input_channels(len(self.skeleton))
                sess = AdapterFreeSession(sess, graph, width, ort_session)
            self._sessions[which] = sess
        return self._sessions[which]

    def _check_channels(self, path, sess) -> None:
        """ModelFolderError unless the generator takes the feature channels model.json's
        ``generator`` config gives (a config left out or edited would fail inside onnxruntime
        on the first fill)."""
        gcfg = self.meta.get("generator", {})
        want = n_input_channels(len(self.skeleton), **feature_options(gcfg))
        shape = next(i.shape for i in sess.get_inputs() if i.name == "features")
        if len(shape) == 3 and isinstance(shape[1], int) and shape[1] != want:
            given = "no 'generator' config" if "generator" not in self.meta else "its 'generator' config"
            raise ModelFolderError(
                f"{path}: takes {shape[1]} feature channels, but model.json has {given}, which gives {want}"
            )
        # A motion DNA: the generator's dna inputs and model.json's generator.dna agree.
        dna = gcfg.get("dna", 0)
        takes = {"dna", "dna_weight"} <= {i.name for i in sess.get_inputs()}
        if isinstance(dna, bool) or not isinstance(dna, int) or dna < 0 or bool(dna) != takes:
            has = "takes a motion DNA" if takes else "takes no motion DNA"
            raise ModelFolderError(
                f"{path}: {has}, but model.json's generator.dna is {dna!r}"
                + (" (a DNA size, a whole number above 0)" if takes else " (0 or absent)")
            )

    def raw(self, rot, root, keys, noise=None, joint_keys=None, dna=None):
        """Network output for a batch: (rot, root, contact prob) in the input's frame,
        unpostprocessed. Only the keyed span goes in, as in training (first key first, last
        key last); frames outside it hold the end keys' (post-processing holds them anyway)."""
        N = rot.shape[1]
        keys = np.asarray(keys, np.int64)
        k0, k1 = int(keys[0]), int(keys[-1])
        q, r, c = self._network(rot[:, k0 : k1 + 1], root[:, k0 : k1 + 1], keys - k0, noise, joint_keys, dna)
        edge = np.r_[np.zeros(k0, np.int64), np.arange(k1 - k0 + 1), np.full(N - k1 - 1, k1 - k0)]
        return q[:, edge], r[:, edge], c[:, edge]

    def dna_inputs(self, batch: int, dna) -> dict:
        """The generator's DNA inputs: (B, C, R) poses and a (B, 1) weight (0: no DNA).
        ``dna``: None, or the DNA poses' local rotations, (R, J, 4) for the whole batch or
        (B, R, J, 4) per window (the root position does not matter: poses are root-relative)."""
        C = n_dna_channels(len(self.skeleton))
        if dna is None:
            return {
                "dna": np.zeros((batch, C, 1), np.float32),
                "dna_weight": np.zeros((batch, 1), np.float32),
            }
        dna = np.asarray(dna)
        if dna.ndim == 3:
            dna = np.repeat(dna[None], batch, 0)
        zero = np.zeros((dna.shape[1], 3))
        poses = np.stack([dna_poses(d, zero, self.skeleton) for d in dna])
        return {"dna": poses, "dna_weight": np.ones((batch, 1), np.float32)}

    def _network(self, rot, root, keys, noise=None, joint_keys=None, dna=None):
        """The generator on one window whose first and last frames are keys, padded to the
        network's multiple by holding the last key, the padded window's last frame a key too:
        every training window ends on a key."""
        skel = self.skeleton
        B, N, J = rot.shape[:3]
        mult = int(self.meta["multiple"])
        pad = -(-max(N + self.pad_tail, self.min_window) // mult) * mult - N
        full = np.ones((1, J + 1), bool)
        if joint_keys is None:
            joint_keys = np.repeat(full, len(keys), 0)
        if pad:
            rot = np.concatenate([rot, np.repeat(rot[:, -1:], pad, 1)], 1)
            root = np.concatenate([root, np.repeat(root[:, -1:], pad, 1)], 1)
            keys = np.r_[keys, N + pad - 1]
            joint_keys = np.concatenate([joint_keys, full])
        gcfg = self.meta.get("generator", {})
        # Without partial keys the adapter's side input (all zeros) is left out where the
        # generator session runs those features on the graph without the adapter.
        lean = joint_keys.all() and isinstance(self.session("generator"), AdapterFreeSession)
        feats, ctx = build_features(
            rot, root, keys, skel, noise, joint_keys=joint_keys, adapter=not lean, **feature_options(gcfg)
        )
        inputs = {"features": feats}
        if gcfg.get("dna"):
            inputs.update(self.dna_inputs(len(feats), dna))
        out = self.session("generator").run(None, inputs)[0]
        o = out.transpose(0, 2, 1)
        f = feats.transpose(0, 2, 1)
        J6 = J * 6
        # The network's 6D residual on the baseline straight to quaternions (no 3x3 matrices
        # in between; bitwise the same as through them), on the network's (B, C, N) layout:
        # one row of frames per channel.
        n = out.shape[-1]
        q = np.empty((B, n, J, 4))
        batch_sixd_to_quat(
            (feats[:, :J6] + out[:, :J6]).reshape(B, J, 6, n), axis=2, out=q.transpose(0, 2, 1, 3)
        )
        croot = (f[..., J6 : J6 + 3] + o[..., J6 : J6 + 3]).astype(np.float64) * ROOT_SCALE
        contacts = _sigmoid(o[..., J6 + 3 : J6 + 7])
        q, wroot = invert_transform(q, croot, ctx["q"], ctx["off"])
        return q[:, :N], wroot[:, :N], contacts[:, :N]

    @property
    def pose_bank(self) -> np.ndarray | None:
        """(P, J, 3) poses of the training data (model.json ``pose_bank``, read and checked
        when the model loads; None where the folder has none): how familiar a shot's keys are
        (pipeline.infer.novelty)."""
        return self._pose_bank

    def _load_pose_bank(self) -> np.ndarray | None:
        name = self.meta.get("pose_bank")
        if name is None:
            return None
        if not isinstance(name, str) or not name:
            raise ModelFolderError(
                f"{self.folder / 'model.json'}: pose_bank must be a file name, not {name!r}"
            )
        path = self.folder / name
        if not path.is_file():
            raise ModelFolderError(f"{path}: the pose bank model.json names is missing")
        check_pose_bank(path, len(self.skeleton))  # its header, before numpy allocates the poses
        try:
            bank = posebank.load(path)
        except ValueError as e:
            raise ModelFolderError(str(e)) from None
        if bank.shape[1] != len(self.skeleton):
            raise ModelFolderError(
                f"{path}: a pose bank of {bank.shape[1]} joints for a model of {len(self.skeleton)}"
            )
        return bank

    @property
    def has_dna(self) -> bool:
        """Whether the generator takes a motion DNA (``fill(..., dna=...)``)."""
        return self.capabilities.dna

    def fill_batch(self, rot, root, keys, noise=None, joint_keys=None, dna=None):
        """Fill a batch sharing its keys; ``joint_keys`` (K, J + 1) marks partial keys (the
        joints, then the root, keyed at each key; the first and last keys full); ``dna`` the
        local rotations of motion-DNA poses, (R, J, 4) or (B, R, J, 4)."""
        if dna is not None and not self.capabilities.dna:
            raise ValueError(f"{self.name}: this model has no motion-DNA encoder")
        keys = np.asarray(keys, np.int64)
        if joint_keys is not None:
            if (np.diff(keys) <= 0).any():
                raise ValueError("with a joint key mask, keys must be sorted and unique")
            joint_keys = check_joint_keys(joint_keys, len(keys), rot.shape[2])
            if joint_keys.all():
                joint_keys = None
        keys = np.unique(keys)
        if np.diff(keys).max() > self.max_gap:
            rot, root, keys, joint_keys = self._insert_keys(rot, root, keys, noise, joint_keys, dna)
        return self._chunked(rot, root, keys, noise, joint_keys, dna, self.feet)

    def _solve(self, rot, root, keys, noise, joint_keys, dna, feet: bool):
        """Networks and post-processing on one window whose gaps all fit the model."""
        if joint_keys is None or self.meta.get("generator", {}).get("key_adapter", False):
            q, r, contacts = self.raw(rot, root, keys, noise, joint_keys, dna)
        else:
            # A network without partial-key inputs would take a partial key for a full pose:
            # it fills from the full keys, and the partial keys are matched afterwards.
            full = joint_keys.all(axis=1)
            q, r, contacts = self.raw(rot, root, keys[full], noise, None, dna)
        q, r = match_keys(q, r, rot[:, keys], root[:, keys], keys, joint_keys)
        if feet:
            # Contact per leg: the ankle (Foot_*) channels 0 and 2.
            for b in range(len(q)):
                q[b] = lock_feet(
                    q[b],
                    r[b],
                    self.skeleton,
                    contacts[b][:, [0, 2]],
                    keys,
                    self.legs,
                    anchor=self.feet_anchor,
                    orient=self.feet_orient,
                )
        return q, r

    def chunk_plan(self, n: int, keys: np.ndarray, joint_keys=None) -> list[tuple[int, int, int, int]]:
        """How a fill of ``n`` frames between sorted ``keys`` is split: [(lo, hi, a, b)], the
        window of frames lo..hi the networks see and the frames a..b of its result kept.

        Up to ``chunk_frames`` frames, one window: the whole shot (the fill is then what it
        always was). Longer fills go through windows of about ``chunk_core`` kept frames, cut
        at full keys (so each kept piece meets the next one at a key, which both leave exact),
        each seeing ``margin`` more frames on both sides (out to the next full key): every
        kept frame then sees all the keys the network's receptive field reaches.

        A gap's fill depends on the keys within the receptive field around it and, through
        the canonical frame, on the window's first key (its position and heading), and on
        where its frames fall in the network's stride. So a long fill differs from one window
        over the whole shot, by about as much as another heading of the first key would make:
        on a 9,692-frame walk (keys every 10 frames) 3.0 degrees per joint on average between
        the two, each 6.9 / 6.8 degrees (root 3.0 / 2.7 cm) from the real motion. Seams are
        keys, exact on both sides. Hierarchical key insertion runs before the windows (on the
        whole shot; its coarse pass goes through windows too).
        """
        keys = np.asarray(keys, np.int64)
        if n <= self.chunk_frames:
            return [(0, n - 1, 0, n - 1)]
        full = keys if joint_keys is None else keys[np.asarray(joint_keys, bool).all(axis=1)]
        seams, nxt = [], int(full[0]) + self.chunk_core
        for k in full[1:-1]:
            if k >= nxt and int(full[-1]) - k >= self.chunk_core // 2:
                seams.append(int(k))
                nxt = int(k) + self.chunk_core
        if not seams:
            return [(0, n - 1, 0, n - 1)]
        bounds = [0, *seams, n - 1]
        plan = []
        for a, b in zip(bounds[:-1], bounds[1:], strict=True):
            i = np.searchsorted(full, a - self.margin, side="right") - 1
            j = np.searchsorted(full, b + self.margin, side="left")
            lo = int(full[i]) if a > 0 and i > 0 else 0
            hi = int(full[j]) if b < n - 1 and j < len(full) - 1 else n - 1
            plan.append((lo, hi, a, b))
        return plan

    def _chunked(self, rot, root, keys, noise, joint_keys, dna, feet: bool):
        """:meth:`_solve` over the windows of :meth:`chunk_plan`: memory follows the window,
        not the shot."""
        plan = self.chunk_plan(rot.shape[1], keys, joint_keys)
        if len(plan) == 1:
            return self._solve(rot, root, keys, noise, joint_keys, dna, feet)
        q = np.empty(rot.shape, np.float32)
        r = np.empty(root.shape, np.float32)
        for lo, hi, a, b in plan:
            at = (keys >= lo) & (keys <= hi)
            qc, rc = self._solve(
                rot[:, lo : hi + 1],
                root[:, lo : hi + 1],
                keys[at] - lo,
                noise,
                None if joint_keys is None else joint_keys[at],
                dna,
                feet,
            )
            q[:, a : b + 1] = qc[:, a - lo : b - lo + 1]
            r[:, a : b + 1] = rc[:, a - lo : b - lo + 1]
        return q, r

    def _insert_keys(self, rot, root, keys, noise, joint_keys=None, dna=None):
        """Hierarchical key insertion for gaps longer than the model was trained on.

        A coarse pass fills the shot at 1/f of the frame rate (every gap then fits), and
        its poses become extra keys, at most ``max_gap / 2`` apart, inside the long gaps;
        the fine pass then fills between all keys. The animator's keys stay exact.
        """
        f = int(np.ceil(np.diff(keys).max() / (0.66 * self.max_gap)))
        # The coarse pass takes the full keys only (partial ones may share a coarse frame).
        full = np.ones(len(keys), bool) if joint_keys is None else joint_keys.all(axis=1)
        ck = np.round(keys[full] / f).astype(np.int64)
        keep = np.r_[True, np.diff(ck) > 0]
        ck, fk_ = ck[keep], keys[full][keep]
        nc = int(ck[-1]) + 1
        c_rot = np.repeat(rot[:, :1], nc, 1).copy()
        c_root = np.repeat(root[:, :1], nc, 1).copy()
        c_rot[:, ck], c_root[:, ck] = rot[:, fk_], root[:, fk_]
        q, r = self._chunked(c_rot, c_root, ck, noise, None, dna, feet=False)
        new = []
        for a, b in zip(keys[:-1], keys[1:], strict=True):
            if b - a > self.max_gap:
                n = int(np.ceil((b - a) / (self.max_gap / 2)))
                new += [int(round(a + (b - a) * i / n)) for i in range(1, n)]
        new = np.array(sorted(set(new) - set(keys.tolist())), np.int64)
        # The coarse pose at fine frame t: between coarse frames floor(t/f) and ceil(t/f).
        x = np.clip(new / f, 0, nc - 1)
        i0 = np.floor(x).astype(np.int64)
        i1 = np.minimum(i0 + 1, nc - 1)
        w = x - i0
        rot, root = rot.copy(), root.copy()
        rot[:, new] = slerp_pairs(q[:, i0], q[:, i1], w[None, :, None])
        root[:, new] = (1 - w)[None, :, None] * r[:, i0] + w[None, :, None] * r[:, i1]
        merged = np.union1d(keys, new)
        if joint_keys is not None:  # inserted keys are full poses; the animator's keep their mask
            mask = np.ones((len(merged), joint_keys.shape[1]), bool)
            mask[np.searchsorted(merged, keys)] = joint_keys
            joint_keys = mask
        return rot, root, merged, joint_keys

    def fill(self, motion: Motion, keys: np.ndarray, seed: int = 0, joint_keys=None, dna=None) -> Motion:
        """Fill ``motion`` between ``keys`` (take ``seed``); ``dna``: a Motion of representative
        poses (see :func:`pipeline.infer.dna_poses.representative_frames`) the fill should contain."""
        if len(self.skeleton) != len(motion.skeleton):
            raise ValueError(
                f"{self.name}: motion has {len(motion.skeleton)} joints, model {len(self.skeleton)}"
            )
        keys = np.asarray(keys, np.int64)
        if joint_keys is None:
            keys = np.unique(keys)
        if len(keys) < 2:
            raise ValueError("in-betweening needs at least two keys")
        q, r = self.fill_batch(
            motion.rotations[None],
            motion.root_positions[None],
            keys,
            take_latent(seed)[None],
            joint_keys,
            None if dna is None else dna.rotations,
        )
        return replace(motion, rotations=q[0], root_positions=r[0])
