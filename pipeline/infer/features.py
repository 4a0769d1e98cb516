"""The network's input, built in numpy (shared by training and the ONNX farm path).

Per frame: the interpolation baseline between the surrounding keys (the network predicts
a residual over it), the dense key format of Generative Tweening (a copy of the nearest
key's pose plus the distance to it), a key flag, and time-to-arrival sinusoids (RMIB) of the
distances to the previous and next key. Windows are first put in a canonical frame: the
first key's root at the origin (X/Z) and facing +X, so the network never sees absolute
position or heading.

Partial keys (some joints only, or the root only) come as a per-key mask ``joint_keys``
(K, J + 1: the joints, then the root; the first and last keys full). Models built with
``key_adapter`` see them as a side input: the main channels are exactly those of the full
keys alone (what a network trained on full keys knows), and :func:`adapter_channels` add,
per frame, the nearest partial key's offsets from that baseline (zero on unkeyed channels),
its mask and how near it is. Without partial keys they are all zero, so the adapter can never
change a fill from full keys. Other models fill from the full keys, and the partial keys are
matched afterwards (pipeline.infer.post.match_keys).
"""

from __future__ import annotations

import os

import numpy as np

from pipeline.motion.fk import fk
from pipeline.motion.rotations import (
    batch_quat_apply,
    batch_quat_mul,
    batch_quat_normalize,
    batch_quat_to_6d,
    slerp_frames,
)

TTA_FREQS = 8
MAX_TTA = 300.0  # frames; the longest gap the embedding distinguishes (10 s at 30 fps)
ROOT_SCALE = 100.0  # cm -> m, so root channels are of order one


NOISE_CHANNELS = 8  # a per-take latent: zeros for the deterministic take, N(0, 1) from the seed otherwise


def n_adapter_channels(n_joints: int) -> int:
    """Partial-key side input: 6D and root offsets, the key's mask, two nearness channels."""
    return n_joints * 6 + 3 + n_joints + 1 + 2


def n_input_channels(n_joints: int, key_adapter: bool = False) -> int:
    return (
        2 * (n_joints * 6 + 3)
        + 2
        + 4 * TTA_FREQS
        + NOISE_CHANNELS
        + (n_adapter_channels(n_joints) if key_adapter else 0)
    )


def check_joint_keys(joint_keys, n_keys: int, n_joints: int) -> np.ndarray:
    """The per-key mask (K, J + 1) as bool, or ValueError saying what is wrong with it."""
    m = np.asarray(joint_keys, bool)
    if m.shape != (n_keys, n_joints + 1):
        raise ValueError(f"joint key mask has shape {m.shape}, expected ({n_keys}, {n_joints + 1})")
    if not (m[0].all() and m[-1].all()):
        raise ValueError("the first and last keys must key every joint and the root (full poses)")
    if not m.any(axis=1).all():
        raise ValueError("a key in the joint key mask keys nothing")
    return m


def n_output_channels(n_joints: int) -> int:
    """Rotation residual (6D), root residual, four foot contacts."""
    return n_joints * 6 + 3 + 4


def key_neighbours(n: int, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each of n frames, the previous key at or before it and the next key at or after it."""
    keys = np.asarray(keys, np.int64)
    idx = np.arange(n)
    pos = np.searchsorted(keys, idx, side="right") - 1
    prev = keys[np.clip(pos, 0, len(keys) - 1)]
    prev = np.where(idx < keys[0], keys[0], prev)
    pos_n = np.searchsorted(keys, idx, side="left")
    nxt = keys[np.clip(pos_n, 0, len(keys) - 1)]
    nxt = np.where(idx > keys[-1], keys[-1], nxt)
    return prev, nxt


def canonical_transform(rot_key: np.ndarray, root_key: np.ndarray, skeleton) -> tuple[np.ndarray, np.ndarray]:
    """(yaw quaternion (B, 4), offset (B, 3)) taking the given key pose to origin, facing +X."""
    from pipeline.data.protocol import facing_turn

    _, pos = fk(rot_key, root_key, skeleton.parents, skeleton.offsets)
    q = facing_turn(pos, skeleton)
    off = np.asarray(root_key, np.float64).copy()
    off[:, 1] = 0.0
    return q, off


def apply_transform(rot, root, q, off):
    """Rotate (B, N, J, 4)/(B, N, 3) windows by yaw q (B, 4) after subtracting off (B, 3)."""
    q = batch_quat_normalize(q)  # (inputs normalised, as scipy's Rotation did)
    root = batch_quat_apply(q[:, None], root - off[:, None])
    rot = rot.astype(np.float64)  # a copy
    rot[:, :, 0] = batch_quat_mul(q[:, None], batch_quat_normalize(rot[:, :, 0]))
    return rot, root


def invert_transform(rot, root, q, off):
    qi = batch_quat_normalize(q)
    qi[:, :3] *= -1
    root = batch_quat_apply(qi[:, None], root) + off[:, None]
    rot = np.array(rot, np.float64)  # a copy
    rot[:, :, 0] = batch_quat_mul(qi[:, None], batch_quat_normalize(rot[:, :, 0]))
    return rot, root


def tta_embedding(d: np.ndarray) -> np.ndarray:
    """Sinusoidal embedding of frame distances (..., ) -> (..., 2 * TTA_FREQS)."""
    d = np.asarray(d)
    if d.ndim == 1 and len(d) > 64:  # frame distances repeat: each distinct one once, gathered
        u, inv = np.unique(d, return_inverse=True)
        if len(u) < len(d) // 2:
            return _tta(u)[inv]
    return _tta(d)


def _tta(d: np.ndarray) -> np.ndarray:
    freqs = np.pi / (MAX_TTA ** (np.arange(TTA_FREQS) / TTA_FREQS))
    a = d[..., None] * freqs
    return np.concatenate([np.sin(a), np.cos(a)], axis=-1)


def interpolate(rot, root, keys, joint_keys=None):
    """Interpolation baseline over a whole window (B, N, J, 4) given sorted key indices.

    With ``joint_keys`` (K, J + 1) each joint (and the root) interpolates between its own keys.
    Also returns, per frame, the nearest key frame of every joint (N, J + 1).
    """
    B, N, J = rot.shape[:3]
    keys = np.asarray(keys, np.int64)
    if joint_keys is None:
        joint_keys = np.ones((len(keys), J + 1), bool)
    out = np.empty((B, N, J, 4))
    ipos = np.empty((B, N, 3))
    nearest = np.empty((N, J + 1), np.int64)
    idx = np.arange(N)
    for at, cols in key_groups(joint_keys):
        prev, nxt = key_neighbours(N, keys[at])
        w = np.where(nxt > prev, (idx - prev) / np.maximum(nxt - prev, 1), 0.0)
        nearest[:, cols] = np.where(idx - prev <= nxt - idx, prev, nxt)[:, None]
        joints = cols[cols < J]
        # (slerp_frames: the SLERP of slerp_pairs, each gap's terms computed once.)
        if len(joints) == J:  # every joint (the usual case): no gather of the joint axis
            out[:] = slerp_frames(rot, prev, nxt, w)
        elif len(joints):
            out[:, :, joints] = slerp_frames(rot[:, :, joints], prev, nxt, w)
        if J in cols:
            ipos[:] = (1 - w)[None, :, None] * root[:, prev] + w[None, :, None] * root[:, nxt]
    return out, ipos, nearest


def key_groups(joint_keys: np.ndarray):
    """(keys, columns) for each distinct key set of a (K, J + 1) mask: the indices into the
    keys that key those columns. Columns sharing a key set (usually all of them) are handled
    together."""
    if joint_keys.size and joint_keys.all():  # full keys: one group, without np.unique's sort
        yield np.arange(joint_keys.shape[0]), np.arange(joint_keys.shape[1])
        return
    patterns, which = np.unique(joint_keys.T, axis=0, return_inverse=True)
    for p, pattern in enumerate(patterns):
        yield np.flatnonzero(pattern), np.flatnonzero(which.ravel() == p)


def feature_options(generator: dict) -> dict:
    """The :func:`build_features` switches a generator config (``model.json``'s "generator",
    or ``asdict(GeneratorConfig)``) was trained with."""
    return {"key_adapter": generator.get("key_adapter", False)}


def build_features(
    rot,
    root,
    keys,
    skeleton,
    noise=None,
    joint_keys=None,
    key_adapter: bool = False,
    adapter: bool = True,
):
    """Network input (B, C, N) and what is needed to decode: canonical frame and baseline.

    ``rot`` (B, N, J, 4), ``root`` (B, N, 3) hold real values at ``keys`` (sorted, shared by
    the batch); other frames are ignored. ``noise`` (B, NOISE_CHANNELS) is the take's
    latent, constant over time (zeros when None). ``joint_keys`` (K, J + 1) marks partial
    keys (module docstring); ``key_adapter`` adds the side input of :func:`adapter_channels`;
    with ``adapter`` False and no partial keys that side input (all zeros then) is left out,
    for the generator without its adapter (:func:`adapter_free_graph`). Without
    ``key_adapter`` each joint's baseline and key copy follow its own keys.
    """
    # Long because it is one vectorised kernel: each channel group is written in place, in the
    # network's (B, C, N) layout and channel order, from intermediates the groups share.
    keys = np.asarray(keys, np.int64)
    B, N, J = rot.shape[:3]
    if joint_keys is not None:
        joint_keys = check_joint_keys(joint_keys, len(keys), J)
    if key_adapter:
        full = np.ones(len(keys), bool) if joint_keys is None else joint_keys.all(axis=1)
        feats, ctx = build_features(rot, root, keys[full], skeleton, noise)
        if not adapter:
            if not full.all():
                raise ValueError("partial keys need the adapter's side input (adapter=True)")
            return feats, ctx
        side = adapter_channels(ctx, keys[~full], None if joint_keys is None else joint_keys[~full])
        return np.ascontiguousarray(np.concatenate([feats, side], axis=1)), ctx
    q, off = canonical_transform(rot[:, keys[0]], root[:, keys[0]], skeleton)
    crot, croot = apply_transform(rot, root, q, off)
    irot, iroot, nearest = interpolate(crot, croot, keys, joint_keys)
    prev, nxt = key_neighbours(N, keys)
    idx = np.arange(N)
    dist = np.minimum(np.abs(idx - prev), np.abs(nxt - idx)).astype(np.float64)
    is_key = np.isin(idx, keys).astype(np.float64)
    tta_ch = np.concatenate(
        [tta_embedding((idx - prev).astype(np.float64)), tta_embedding((nxt - idx).astype(np.float64))], -1
    )
    latent = np.zeros((B, 1, NOISE_CHANNELS)) if noise is None else np.asarray(noise)[:, None, :]
    per_frame = np.concatenate([(dist / 30.0)[:, None], is_key[:, None], tta_ch], axis=-1)  # (N, 2 + 4F)
    # Written straight into the network's (B, C, N) float32 layout, group by group (each
    # value cast from float64 as the concatenated float64 array's cast did: the same bits).
    feats = np.empty((B, 2 * (J * 6 + 3) + per_frame.shape[-1] + NOISE_CHANNELS, N), np.float32)
    by_frame = feats.transpose(0, 2, 1)  # (B, N, C) view

    def sixd(lo):  # (B, N, J, 6) view of the J * 6 channels from ``lo``
        return feats[:, lo : lo + J * 6].reshape(B, J, 6, N).transpose(0, 3, 1, 2)

    batch_quat_to_6d(irot, out=sixd(0))
    at = J * 6
    by_frame[..., at : at + 3] = iroot / ROOT_SCALE
    at += 3
    if (nearest[:, :J] == nearest[:, :1]).all():  # the nearest key's pose (one key set: a gather)
        # 6D of the key frames only, then gathered: the same element-wise arithmetic.
        sixd(at)[:] = batch_quat_to_6d(crot[:, keys])[:, np.searchsorted(keys, nearest[:, 0])]
    else:
        batch_quat_to_6d(np.take_along_axis(crot, nearest[None, :, :J, None], axis=1), out=sixd(at))
    at += J * 6
    by_frame[..., at : at + 3] = croot[:, nearest[:, J]] / ROOT_SCALE
    at += 3
    by_frame[..., at : at + per_frame.shape[-1]] = per_frame
    at += per_frame.shape[-1]
    by_frame[..., at : at + NOISE_CHANNELS] = latent
    ctx = {"q": q, "off": off, "irot": irot, "iroot": iroot, "crot": crot, "croot": croot}
    return feats, ctx


ADAPTER_REACH = 15.0  # frames: nearness exp(-d / this) of the nearest partial key


def adapter_channels(ctx: dict, keys: np.ndarray, joint_keys) -> np.ndarray:
    """(B, C, N) side input of ``key_adapter`` models: for each frame, the nearest partial key
    (``keys`` (P,), ``joint_keys`` (P, J + 1)): its keyed channels' offsets from the full-key
    baseline at that key (6D and root, in the canonical frame; 0 where unkeyed), its mask, and
    its nearness exp(-d / ADAPTER_REACH) split into before and after it. All zero when P = 0."""
    crot, croot, irot, iroot = ctx["crot"], ctx["croot"], ctx["irot"], ctx["iroot"]
    B, N, J = crot.shape[:3]
    side = np.zeros((B, N, n_adapter_channels(J)), np.float32)
    if len(keys) == 0:
        return np.ascontiguousarray(side.transpose(0, 2, 1))
    keys = np.asarray(keys, np.int64)
    m = np.asarray(joint_keys, bool)
    d6 = batch_quat_to_6d(crot[:, keys]) - batch_quat_to_6d(irot[:, keys])
    d6 = d6 * m[None, :, :J, None]  # (B, P, J, 6)
    droot = (croot[:, keys] - iroot[:, keys]) / ROOT_SCALE * m[None, :, J:]
    idx = np.arange(N)
    p = np.abs(idx[:, None] - keys[None]).argmin(axis=1)  # nearest partial key of each frame
    d = idx - keys[p]
    near = np.exp(-np.abs(d) / ADAPTER_REACH)
    side[..., : J * 6] = d6.reshape(B, -1, J * 6)[:, p]
    side[..., J * 6 : J * 6 + 3] = droot[:, p]
    side[..., J * 6 + 3 : J * 7 + 4] = m[p]
    side[..., -2] = near * (d <= 0)
    side[..., -1] = near * (d >= 0)
    return np.ascontiguousarray(side.transpose(0, 2, 1))


_ADAPTER_FREE: dict = {}  # (path, mtime, size, joints) -> graph bytes or None, per process


def adapter_free_graph(path, n_joints: int, frames: int = 64) -> bytes | None:
    """:func:`build_adapter_free_graph`, once per process for each file."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    key = (str(path), st.st_mtime_ns, st.st_size, n_joints, frames)
    if key not in _ADAPTER_FREE:
        _ADAPTER_FREE[key] = build_adapter_free_graph(path, n_joints, frames)
    return _ADAPTER_FREE[key]


class AdapterFreeSession:
    """The generator's session for a model with a partial-key adapter: features without the
    adapter's side input (``width`` channels: no partial keys) run on the adapter-free graph
    (made by ``make`` from its bytes on first use), others on the whole graph ``full``."""

    def __init__(self, full, graph: bytes, width: int, make):
        self.full, self.graph, self.width, self.make = full, graph, width, make
        self.lean = None

    def run(self, names, feeds):
        if feeds["features"].shape[1] != self.width:
            return self.full.run(names, feeds)
        if self.lean is None:
            self.lean = self.make(self.graph)
        return self.lean.run(names, feeds)

    def __getattr__(self, name):  # get_inputs() and the rest: the whole graph's
        return getattr(self.full, name)


def prune(g) -> None:
    """Drop the nodes and initializers of an ONNX graph that no graph output needs."""
    need = {o.name for o in g.output}
    live = []
    for n in reversed(list(g.node)):
        if need & set(n.output):
            live.append(n)
            need.update(n.input)
    del g.node[:]
    g.node.extend(reversed(live))
    inits = [t for t in g.initializer if t.name in need]
    del g.initializer[:]
    g.initializer.extend(inits)


def build_adapter_free_graph(path, n_joints: int, frames: int = 64) -> bytes | None:
    """The generator ONNX graph at ``path`` without its partial-key adapter, as bytes for
    onnxruntime; it takes the features without :func:`adapter_channels`.

    Fills from full keys give the adapter all-zero input, and its two bias-free convolutions
    around a PReLU then add exactly zero (``Generator.adapter``): 0.30 MFLOP a frame of
    zeros. Built at load time from the same graph (so from the same weights, and the model's
    hash and files are unchanged): the adapter's nodes are dropped, the sum they fed is
    replaced by its other input, the main input slice ends at the main channels. The result
    is checked against the whole graph on random features with a zero side input (it must be
    bitwise the same) before it is used. None where that cannot be done: the ``onnx`` package
    missing (it comes with the ``train`` extra; the farm then runs the whole graph, as
    before), no adapter, a graph of another shape, or outputs that differ.
    """
    # Long because it is one ONNX graph edit read top to bottom: find the adapter, rewire its
    # sum, narrow the input, prune, and check the result against the whole graph.
    try:
        import onnx
        import onnxruntime as ort
        from onnx import numpy_helper
    except ImportError:
        return None
    try:
        model = onnx.load(str(path))
    except Exception:  # an unreadable graph is named by the session that loads it
        return None
    g = model.graph
    adapter = [n for n in g.node if n.name.startswith("/adapter/")]
    inputs = [i for i in g.input if i.name == "features"]
    if not adapter or not inputs or len(g.input) != 1:
        return None
    ids = {id(n) for n in adapter}
    others = [n for n in g.node if id(n) not in ids]
    outs = {o for n in adapter for o in n.output if any(o in m.input for m in others)}
    sums = [m for m in others if outs & set(m.input)]
    if len(outs) != 1 or len(sums) != 1 or sums[0].op_type != "Add":
        return None
    (out,), add = outs, sums[0]
    keep = [i for i in add.input if i != out]
    side = [n for n in others if adapter[0].input[0] in n.output]
    main = [n for n in others if n.op_type == "Slice" and n.input[0] == "features" and n not in side]
    dim = inputs[0].type.tensor_type.shape.dim
    n_side = n_adapter_channels(n_joints)
    if len(keep) != 1 or len(main) != 1 or len(side) != 1 or len(dim) != 3 or not dim[1].dim_value:
        return None
    n_in = dim[1].dim_value
    if n_in != n_input_channels(n_joints, key_adapter=True) or any(o.name == add.output[0] for o in g.output):
        return None
    for n in others:
        for k, name in enumerate(n.input):
            if name == add.output[0]:
                n.input[k] = keep[0]
    g.initializer.append(
        numpy_helper.from_array(np.array([n_in - n_side], np.int64), "adapter_free/main_end")
    )
    main[0].input[2] = "adapter_free/main_end"
    dim[1].dim_value = n_in - n_side
    prune(g)  # what no output needs any more: the adapter, its slice, the shape arithmetic
    lean = model.SerializeToString()
    try:
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = opts.inter_op_num_threads = 1
        x = np.random.default_rng(0).normal(size=(1, n_in, frames)).astype(np.float32)
        x[:, n_in - n_side :] = 0.0
        cpu = ["CPUExecutionProvider"]
        a = ort.InferenceSession(str(path), opts, providers=cpu).run(None, {"features": x})[0]
        b = ort.InferenceSession(lean, opts, providers=cpu).run(None, {"features": x[:, : n_in - n_side]})[0]
    except Exception:
        return None
    return lean if np.array_equal(a, b) else None
