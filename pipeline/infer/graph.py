"""Load-time rewrites of the generator's ONNX graph for onnxruntime's CPU kernels.

The exported generator is a 1D convolutional network on (batch, channels, frames). On one
core onnxruntime runs its 1D convolutions through im2col and sgemm (~100 GFLOP/s here), its
stride-2 ConvTransposes through sgemm and col2im, and the element-wise ops (PReLU, the
residual scales, the nearest-neighbour upsampling written as Unsqueeze/Tile/Reshape) one by
one: the network took about 2.3x its FLOPs at the core's sgemm peak (``tween bench
--speed``). :func:`fast_graph` rewrites it, in memory and from the same weights (the
model's files and hash are unchanged), into the same network on (batch, channels, 1, frames):

* every Conv / ConvTranspose / AveragePool becomes its 2D form with a 1-row kernel, so that
  onnxruntime's NCHWc layout transformer (``ORT_ENABLE_ALL``) runs the convolutions with its
  direct MLAS kernels (~145 GFLOP/s, bias fused) instead of im2col + sgemm;
* each stride-2 ConvTranspose becomes two kernel-2 convolutions (its even and odd output
  frames, NCHWc convolutions too) whose results are interleaved; the up block's PReLU and
  residual sum run on each half before the interleave, so its skip (x upsampled, or its
  1x1 projection) is x itself (the projection on half the frames) and the upsampling goes;
* elsewhere the upsampling becomes a nearest-neighbour Resize (the same values: a copy);
* a positive scalar residual weight after a PReLU is folded into the convolution before it
  (c · PReLU(z) = PReLU(c · z) for c > 0), together with the per-channel affine between the
  two (onnxruntime folds that one itself, in the same way);
* a Slice that keeps every channel of the input is dropped.

Folded weights and the NCHWc kernels sum in another order, so the result differs from the
plain graph by float32 rounding (~1e-6 of the output's scale, as onnxruntime's own
optimisation levels differ from each other); it is checked against the plain graph on random
features before it is used (within :data:`TOLERANCE` of the output's scale). Anything the
rewrite does not recognise (another op, a graph with more inputs such as a DNA model's), or
a graph that fails the check, gives None and the plain graph runs, as before.
"""

from __future__ import annotations

import hashlib
import os

import numpy as np

#: The largest difference from the plain graph accepted, relative to the output's largest
#: magnitude (float32 rounding of reordered sums is ~1e-7 of it).
TOLERANCE = 1e-5

_SPATIAL = ("Conv", "ConvTranspose", "AveragePool")
_CACHE: dict = {}  # (path, mtime, size) or the bytes' digest -> rewritten bytes or None, per process
_ELEMENTWISE = ("Mul", "Add", "Sub", "PRelu")


class _Unsupported(Exception):
    """A graph this rewrite does not know how to handle (the plain graph is used)."""


def fast_graph_requested() -> bool:
    """Whether this process asks for the rewritten generator (``TWEEN_FAST_GRAPH`` 1, true,
    yes or on); the graph as exported otherwise."""
    return os.environ.get("TWEEN_FAST_GRAPH", "0").strip().lower() in ("1", "true", "yes", "on")


def fast_graph(
    graph, frames: int = 256, fold: bool = True, nchwc: bool = True, split_transposed: bool = True
) -> bytes | None:
    """The rewritten generator (module docstring) as bytes for onnxruntime, or None where
    it cannot be made or checked (no ``onnx`` package, an unknown op or pattern, outputs that
    differ). ``graph``: a file or a graph's bytes. ``fold``: fold residual scales into the
    convolutions; ``nchwc``: the 2D form."""
    try:
        import onnx
    except ImportError:
        return None
    try:
        model = onnx.load_from_string(graph) if isinstance(graph, bytes) else onnx.load(str(graph))
    except Exception:
        return None
    try:
        _drop_full_slices(model.graph)
        if fold:
            _fold_scales(model.graph)
        if nchwc:
            _to_2d(model.graph)
            if split_transposed:
                _split_transposed(model.graph)
                prune(model.graph)  # (the folded Muls, which still read the PReLUs)
                _interleave_after_residual(model.graph)
        prune(model.graph)
        out = model.SerializeToString()
    except _Unsupported:
        return None
    return out if check_graph(graph, out, frames) is not None else None


def cached_fast_graph(graph) -> bytes | None:
    """:func:`fast_graph` once per process for each file (or graph bytes)."""
    if isinstance(graph, bytes):
        key = ("bytes", hashlib.sha256(graph).hexdigest())
    else:
        try:
            st = os.stat(graph)
        except OSError:
            return None
        key = (str(graph), st.st_mtime_ns, st.st_size)
    if key not in _CACHE:
        _CACHE[key] = fast_graph(graph)
    return _CACHE[key]


def check_graph(plain, rewritten: bytes, frames: int = 256, seed: int = 0) -> float | None:
    """Largest difference between the two graphs' outputs on random features (relative to
    the plain output's largest magnitude), or None if it is over :data:`TOLERANCE`, the
    outputs differ in shape, or either graph fails to run."""
    import onnxruntime as ort

    try:
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = opts.inter_op_num_threads = 1
        cpu = ["CPUExecutionProvider"]
        a_sess = ort.InferenceSession(plain if isinstance(plain, bytes) else str(plain), opts, providers=cpu)
        b_sess = ort.InferenceSession(rewritten, opts, providers=cpu)
        rng = np.random.default_rng(seed)
        feeds = {}
        for i in a_sess.get_inputs():
            dims = [d if isinstance(d, int) else 1 for d in i.shape]
            if len(dims) == 3 and not isinstance(i.shape[2], int):
                dims[2] = frames
            feeds[i.name] = rng.normal(size=dims).astype(np.float32)
        a = a_sess.run(None, feeds)
        b = b_sess.run(None, feeds)
    except Exception:
        return None
    worst = 0.0
    for x, y in zip(a, b, strict=True):
        if x.shape != y.shape or not np.isfinite(y).all():
            return None
        worst = max(worst, float(np.abs(x - y).max() / max(np.abs(x).max(), 1e-30)))
    return worst if worst <= TOLERANCE else None


# ---------------------------------------------------------------------------------------
# graph helpers


class _Graph:
    """Look-ups over a GraphProto: constants (initializers and Constant nodes), producers
    and consumers of each tensor."""

    def __init__(self, g):
        from onnx import numpy_helper

        self.g = g
        self.inits = {t.name: t for t in g.initializer}
        self.consts = {}
        for n in g.node:
            if n.op_type == "Constant" and len(n.attribute) == 1 and n.attribute[0].name == "value":
                self.consts[n.output[0]] = numpy_helper.to_array(n.attribute[0].t)
        self.producer = {o: n for n in g.node for o in n.output}
        self.consumers: dict[str, list] = {}
        for n in g.node:
            for i in n.input:
                self.consumers.setdefault(i, []).append(n)
        self.outputs = {o.name for o in g.output}

    def value(self, name: str) -> np.ndarray | None:
        from onnx import numpy_helper

        if name in self.inits:
            return numpy_helper.to_array(self.inits[name])
        return self.consts.get(name)

    def only_consumer(self, name: str):
        users = self.consumers.get(name, [])
        return users[0] if len(users) == 1 and name not in self.outputs else None

    def set_init(self, name: str, value: np.ndarray) -> str:
        """A new initializer ``name`` (made unique) holding ``value``; returns its name."""
        from onnx import numpy_helper

        base, k = name, 0
        while name in self.inits or name in self.consts or name in self.producer:
            k += 1
            name = f"{base}_{k}"
        t = numpy_helper.from_array(np.ascontiguousarray(value), name)
        self.g.initializer.append(t)
        self.inits[name] = t
        return name


def _attrs(node) -> dict:
    from onnx import helper

    return {a.name: helper.get_attribute_value(a) for a in node.attribute}


def _set_attr(node, name: str, value) -> None:
    from onnx import helper

    for k, a in enumerate(node.attribute):
        if a.name == name:
            del node.attribute[k]
            break
    node.attribute.append(helper.make_attribute(name, value))


def _rename_input(gr: _Graph, old: str, new: str) -> None:
    for n in gr.consumers.get(old, []):
        for k, name in enumerate(n.input):
            if name == old:
                n.input[k] = new
    if old in gr.outputs:
        raise _Unsupported(f"{old} is a graph output")


def prune(g) -> None:
    """Drop the nodes and initializers no graph output needs."""
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


# ---------------------------------------------------------------------------------------
# the rewrites


def _drop_full_slices(g) -> None:
    """A Slice of a graph input along its channel axis that keeps every channel: its
    consumers read the input itself (the same values)."""
    gr = _Graph(g)
    dims = {
        i.name: [d.dim_value if d.HasField("dim_value") else None for d in i.type.tensor_type.shape.dim]
        for i in g.input
    }
    for n in list(g.node):
        if n.op_type != "Slice" or n.input[0] not in dims or len(n.input) < 4:
            continue
        starts, ends, axes = (gr.value(n.input[k]) for k in (1, 2, 3))
        steps = gr.value(n.input[4]) if len(n.input) > 4 and n.input[4] else np.ones(1, np.int64)
        if starts is None or ends is None or axes is None or steps is None:
            continue
        if not (starts.shape == ends.shape == axes.shape == steps.shape == (1,)):
            continue
        c = dims[n.input[0]][int(axes[0])] if int(axes[0]) >= 0 else None
        if c and int(starts[0]) == 0 and int(ends[0]) >= c and int(steps[0]) == 1:
            _rename_input(gr, n.output[0], n.input[0])


def _fold_scales(g) -> None:
    """Conv or ConvTranspose → [Mul per-channel → Add per-channel] → PRelu → Mul by a positive scalar c:
    the affine and c go into the Conv's weights and bias (w·s·c, (b·s + t)·c), the Mul by c
    is dropped (PReLU(c·z) = c·PReLU(z) for c > 0). Each tensor in the chain must have
    that one consumer."""
    gr = _Graph(g)
    for conv in list(g.node):
        if conv.op_type not in ("Conv", "ConvTranspose") or len(conv.input) < 2:
            continue
        w = gr.value(conv.input[1])
        if w is None or w.ndim != 3 or conv.input[1] not in gr.inits:
            continue
        # Output channels: Conv weights (Cout, Cin/g, k), ConvTranspose (Cin, Cout/g, k).
        out_axis = 0 if conv.op_type == "Conv" else 1
        if out_axis and _attrs(conv).get("group", 1) != 1:
            continue
        cout = w.shape[out_axis]
        b = gr.value(conv.input[2]) if len(conv.input) > 2 and conv.input[2] else np.zeros(cout, w.dtype)
        if b is None or b.shape != (cout,):
            continue
        scale, shift = np.ones(cout, np.float64), np.zeros(cout, np.float64)
        node = gr.only_consumer(conv.output[0])
        chain = []
        for op in ("Mul", "Add"):
            if node is None or node.op_type != op:
                continue
            other = [i for i in node.input if i != chain_out(conv, chain)]
            v = gr.value(other[0]) if len(other) == 1 else None
            v = _per_channel(v, cout)
            if v is None:
                break
            if op == "Mul":
                scale, shift = scale * v, shift * v
            else:
                shift = shift + v
            chain.append(node)
            node = gr.only_consumer(node.output[0])
        if node is None or node.op_type != "PRelu" or len(chain) not in (0, 2):
            continue
        prelu = node
        mul = gr.only_consumer(prelu.output[0])
        if mul is None or mul.op_type != "Mul":
            continue
        other = [i for i in mul.input if i != prelu.output[0]]
        c = gr.value(other[0]) if len(other) == 1 else None
        if c is None or c.size != 1 or not float(c.ravel()[0]) > 0:
            continue
        c = float(c.ravel()[0])
        per_out = (scale * c).reshape([-1 if k == out_axis else 1 for k in range(3)])
        w2 = (w.astype(np.float64) * per_out).astype(np.float32)
        b2 = ((b.astype(np.float64) * scale + shift) * c).astype(np.float32)
        conv.input[1] = gr.set_init(conv.input[1] + "/folded", w2)
        if len(conv.input) > 2:
            conv.input[2] = gr.set_init((conv.input[2] or conv.name + ".bias") + "/folded", b2)
        else:
            conv.input.append(gr.set_init(conv.name + ".bias/folded", b2))
        # PReLU straight on the conv's output; the Mul's consumers read the PReLU's.
        prelu.input[0] = conv.output[0]
        _rename_input(gr, mul.output[0], prelu.output[0])


def chain_out(conv, chain) -> str:
    return chain[-1].output[0] if chain else conv.output[0]


def _per_channel(v, c: int) -> np.ndarray | None:
    """A (1, C, 1) / (C, 1) / scalar constant as a (C,) float64 vector, or None."""
    if v is None or not np.issubdtype(v.dtype, np.floating):
        return None
    if v.size == 1:
        return np.full(c, float(v.ravel()[0]))
    if v.size == c and v.ndim >= 2 and v.shape[-1] == 1 and v.shape[-2] == c:
        return v.reshape(c).astype(np.float64)
    return None


def _to_2d(g) -> None:
    """The graph on (B, C, 1, N) instead of (B, C, N) (module docstring). Raises
    _Unsupported on anything it does not recognise."""
    from onnx import TensorProto, helper

    gr = _Graph(g)
    if len(g.input) != 1 or len(g.output) != 1:
        raise _Unsupported("one input and one output expected")
    inp, out = g.input[0], g.output[0]
    if len(inp.type.tensor_type.shape.dim) != 3 or len(out.type.tensor_type.shape.dim) != 3:
        raise _Unsupported("(batch, channels, frames) input and output expected")
    axes2 = gr.set_init("to_2d/axis2", np.array([2], np.int64))
    x4 = "to_2d/" + inp.name
    y4 = "to_2d/" + out.name
    # Every 3D tensor becomes 4D; upsampling chains are replaced.
    upsample = _upsample_chains(gr)
    done = set()
    new_nodes = [helper.make_node("Unsqueeze", [inp.name, axes2], [x4], name="to_2d/unsqueeze")]
    rename = {inp.name: x4}
    # Shape arithmetic (the whole graph's slice of the adapter's channels): the batch and
    # channel sizes read from a tensor's shape are the same in 2D.
    shapes: set[str] = set()
    for n in g.node:
        if id(n) in done:
            continue
        if n.op_type == "Constant":
            new_nodes.append(n)
            continue
        if n.op_type == "Shape":
            users = gr.consumers.get(n.output[0], [])
            for u in users:
                ix = gr.value(u.input[1]) if u.op_type == "Gather" else None
                if ix is None or ix.size != 1 or not 0 <= int(ix.ravel()[0]) < 2 or _attrs(u).get("axis", 0):
                    raise _Unsupported(f"{n.name}: a shape read other than batch or channels")
            if _attrs(n):
                raise _Unsupported(f"{n.name}: Shape with start/end")
        live = [i for i in n.input if i and gr.value(i) is None]
        if n.op_type == "Shape" or (live and all(i in shapes for i in live)):
            if n.op_type not in (
                "Shape",
                "Gather",
                "Sub",
                "Add",
                "Mul",
                "Unsqueeze",
                "Concat",
                "Squeeze",
                "Cast",
            ):
                raise _Unsupported(f"{n.name}: {n.op_type} in shape arithmetic")
            for k, name in enumerate(n.input):
                n.input[k] = rename.get(name, name)
            shapes.update(n.output)
            new_nodes.append(n)
            continue
        if id(n) in upsample:
            src, reshape, members = upsample[id(n)]
            done.update(members)
            scales = gr.set_init("to_2d/upsample_scales", np.array([1, 1, 1, 2], np.float32))
            new_nodes.append(
                helper.make_node(
                    "Resize",
                    [rename.get(src, src), "", scales],
                    [reshape.output[0]],
                    name=reshape.name + "/resize",
                    mode="nearest",
                    coordinate_transformation_mode="asymmetric",
                    nearest_mode="floor",
                )
            )
            continue
        for k, name in enumerate(n.input):
            n.input[k] = rename.get(name, name)
        if n.op_type in _SPATIAL:
            _spatial_2d(gr, n)
        elif n.op_type in _ELEMENTWISE:
            for k, name in enumerate(n.input):
                v = gr.value(name)
                if name == n.input[0] and n.op_type == "PRelu":
                    continue
                if v is not None:
                    if v.ndim >= 2:  # per-channel (…, C, 1): one more unit axis
                        n.input[k] = gr.set_init(name + "/2d", v.reshape(*v.shape, 1))
                elif name not in gr.producer and name != x4 and not name.startswith("to_2d/"):
                    raise _Unsupported(f"{n.name}: input {name} of unknown shape")
        elif n.op_type == "Slice" and n.input[0] not in shapes:
            axes = gr.value(n.input[3]) if len(n.input) > 3 else None
            if axes is None or (axes < 0).any() or (axes >= 2).any():
                raise _Unsupported(f"{n.name}: a Slice along frames")
        else:
            raise _Unsupported(f"{n.name}: {n.op_type}")
        for k, name in enumerate(n.output):
            if name == out.name:
                n.output[k] = y4
        new_nodes.append(n)
    new_nodes.append(helper.make_node("Squeeze", [y4, axes2], [out.name], name="to_2d/squeeze"))
    del g.node[:]
    g.node.extend(new_nodes)
    del g.value_info[:]
    out.type.tensor_type.elem_type = TensorProto.FLOAT


def _spatial_2d(gr: _Graph, n) -> None:
    a = _attrs(n)
    if a.get("auto_pad", b"NOTSET") not in (b"NOTSET", "NOTSET"):
        raise _Unsupported(f"{n.name}: auto_pad")
    k = a.get("kernel_shape")
    if n.op_type != "AveragePool":
        w = gr.value(n.input[1])
        if w is None or w.ndim != 3:
            raise _Unsupported(f"{n.name}: weights not a 1D constant")
        n.input[1] = gr.set_init(n.input[1] + "/2d", w.reshape(w.shape[0], w.shape[1], 1, w.shape[2]))
        k = k or [w.shape[2]]
    if k is None or len(k) != 1:
        raise _Unsupported(f"{n.name}: kernel")
    _set_attr(n, "kernel_shape", [1, int(k[0])])
    pads = a.get("pads", [0, 0])
    _set_attr(n, "pads", [0, int(pads[0]), 0, int(pads[1])])
    for name, default in (("strides", 1), ("dilations", 1)):
        if name in a or name == "strides":
            v = a.get(name, [default])
            _set_attr(n, name, [1, int(v[0])])
    if "output_padding" in a:
        _set_attr(n, "output_padding", [0, int(a["output_padding"][0])])
    if "output_shape" in a:
        raise _Unsupported(f"{n.name}: output_shape")
    if n.op_type == "AveragePool" and a.get("ceil_mode", 0):
        raise _Unsupported(f"{n.name}: ceil_mode")


def _upsample_chains(gr: _Graph) -> dict:
    """{id(first node): (source tensor, Reshape node, ids of the chain's nodes)} for each
    nearest-neighbour ×2 upsampling written as Unsqueeze(x, 3) → Tile(1, 1, 1, 2) →
    Reshape(Concat(Slice(Shape(·), 0, 2), -1))."""
    chains = {}
    for n in gr.g.node:
        if n.op_type != "Unsqueeze":
            continue
        ax = gr.value(n.input[1]) if len(n.input) > 1 else np.array(_attrs(n).get("axes", []))
        tile = gr.only_consumer(n.output[0])
        if ax is None or ax.tolist() != [3] or tile is None or tile.op_type != "Tile":
            continue
        rep = gr.value(tile.input[1])
        if rep is None or rep.tolist() != [1, 1, 1, 2]:
            continue
        users = gr.consumers.get(tile.output[0], [])
        reshape = [u for u in users if u.op_type == "Reshape" and u.input[0] == tile.output[0]]
        shape = [u for u in users if u.op_type == "Shape"]
        if len(reshape) != 1 or len(users) != 1 + len(shape):
            continue
        members = {id(n), id(tile), id(reshape[0])}
        # The target shape: Concat(Slice(Shape(tile), [0], [2]), [-1]) (or a constant).
        tgt = gr.value(reshape[0].input[1])
        if tgt is None:
            cat = gr.producer.get(reshape[0].input[1])
            if cat is None or cat.op_type != "Concat" or len(cat.input) != 2:
                continue
            sl = gr.producer.get(cat.input[0])
            last = gr.value(cat.input[1])
            if sl is None or sl.op_type != "Slice" or last is None or last.tolist() != [-1]:
                continue
            sh = gr.producer.get(sl.input[0])
            st, en = gr.value(sl.input[1]), gr.value(sl.input[2])
            if sh is None or sh.op_type != "Shape" or sh.input[0] != tile.output[0]:
                continue
            if st is None or en is None or st.tolist() != [0] or en.tolist() != [2]:
                continue
            if len(sl.input) > 3 and (gr.value(sl.input[3]) is None or gr.value(sl.input[3]).tolist() != [0]):
                continue
            members |= {id(cat), id(sl), id(sh)}
        elif tgt.tolist()[2:] != [-1] or len(tgt) != 3:
            continue
        chains[id(n)] = (n.input[0], reshape[0], members)
    return chains


def _split_transposed(g) -> None:
    """Each 2D ConvTranspose of stride 2, kernel 4, padding 1 (the upsampling convolutions)
    as two convolutions of kernel 2 (its even and its odd output frames, which onnxruntime
    runs as NCHWc convolutions, ConvTranspose having no NCHWc form), interleaved:

        y[2t] = W₁ᵀ x[t] + W₃ᵀ x[t−1],  y[2t+1] = W₂ᵀ x[t] + W₀ᵀ x[t+1]

    (the same products, summed in another order)."""
    from onnx import helper

    gr = _Graph(g)
    nodes = []
    for n in g.node:
        a = _attrs(n)
        w = gr.value(n.input[1]) if n.op_type == "ConvTranspose" else None
        if (
            w is None
            or w.ndim != 4
            or w.shape[2:] != (1, 4)
            or a.get("strides") != [1, 2]
            or a.get("pads") != [0, 1, 0, 1]
            or a.get("group", 1) != 1
            or a.get("dilations", [1, 1]) != [1, 1]
            or any(a.get("output_padding", [0, 0]))
            or "output_shape" in a
        ):
            nodes.append(n)
            continue
        wt = w.transpose(1, 0, 2, 3)  # (Cout, Cin, 1, 4)
        even = gr.set_init(n.input[1] + "/even", np.ascontiguousarray(wt[..., [3, 1]]))
        odd = gr.set_init(n.input[1] + "/odd", np.ascontiguousarray(wt[..., [2, 0]]))
        bias = [n.input[2]] if len(n.input) > 2 and n.input[2] else []
        ax = gr.set_init("split_transposed/axis4", np.array([4], np.int64))
        shape = gr.set_init("split_transposed/shape", np.array([0, 0, 1, -1], np.int64))
        base = n.name or n.output[0]
        parts = []
        for tag, wname, pads in (("even", even, [0, 1, 0, 0]), ("odd", odd, [0, 0, 0, 1])):
            y = f"{base}/{tag}"
            nodes.append(
                helper.make_node(
                    "Conv",
                    [n.input[0], wname, *bias],
                    [y],
                    name=y,
                    kernel_shape=[1, 2],
                    pads=pads,
                    strides=[1, 1],
                )
            )
            nodes.append(helper.make_node("Unsqueeze", [y, ax], [y + "/5d"], name=y + "/unsqueeze"))
            parts.append(y + "/5d")
        nodes.append(
            helper.make_node("Concat", parts, [base + "/interleaved"], name=base + "/concat", axis=4)
        )
        nodes.append(
            helper.make_node("Reshape", [base + "/interleaved", shape], [n.output[0]], name=base + "/reshape")
        )
    del g.node[:]
    g.node.extend(nodes)


def _interleave_after_residual(g) -> None:
    """An up block after :func:`_split_transposed`: ``PReLU(interleave(even, odd)) + c ·
    up(x)`` (up: the nearest ×2 Resize, optionally followed by a 1×1 projection) becomes
    ``interleave(PReLU(even) + c · x', PReLU(odd) + c · x')`` with x' = x (or its projection,
    now on the frames before the upsampling): the same values frame by frame (the upsampled
    skip is each frame of x' twice), without the Resize and with the skip's Mul and
    projection on half the frames."""
    from onnx import helper

    gr = _Graph(g)
    drop, insert = set(), {}
    for rs in g.node:
        if rs.op_type != "Reshape" or not rs.name.endswith("/reshape"):
            continue
        cat = gr.producer.get(rs.input[0])
        if cat is None or cat.op_type != "Concat" or len(cat.input) != 2:
            continue
        unsq = [gr.producer.get(i) for i in cat.input]
        if any(
            u is None or u.op_type != "Unsqueeze" or gr.only_consumer(u.output[0]) is not cat for u in unsq
        ):
            continue
        prelu = gr.only_consumer(rs.output[0])
        if prelu is None or prelu.op_type != "PRelu" or prelu.input[0] != rs.output[0]:
            continue
        add = gr.only_consumer(prelu.output[0])
        if add is None or add.op_type != "Add" or len(add.input) != 2:
            continue
        other = add.input[1] if add.input[0] == prelu.output[0] else add.input[0]
        mul = gr.producer.get(other)
        if mul is None or mul.op_type != "Mul" or gr.only_consumer(mul.output[0]) is not add:
            continue
        c = [i for i in mul.input if gr.value(i) is not None]
        src = [i for i in mul.input if gr.value(i) is None]
        if len(c) != 1 or len(src) != 1 or gr.value(c[0]).size != 1:
            continue
        proj = gr.producer.get(src[0])
        if proj is not None and proj.op_type == "Conv":
            a = _attrs(proj)
            w = gr.value(proj.input[1])
            if (
                w is None
                or w.shape[2:] != (1, 1)
                or a.get("strides", [1, 1]) != [1, 1]
                or any(a.get("pads", [0, 0, 0, 0]))
                or a.get("group", 1) != 1
                or gr.only_consumer(proj.output[0]) is not mul
            ):
                continue
            resize = gr.producer.get(proj.input[0])
            user = proj
        else:
            resize, user = proj, mul
        if resize is None or resize.op_type != "Resize" or gr.only_consumer(resize.output[0]) is not user:
            continue
        sc = gr.value(resize.input[2]) if len(resize.input) > 2 else None
        if sc is None or sc.tolist() != [1, 1, 1, 2] or _attrs(resize).get("mode") != b"nearest":
            continue
        # The skip on x's own frames; each half gets its PReLU and the residual sum.
        for k, name in enumerate(user.input):
            if name == resize.output[0]:
                user.input[k] = resize.input[0]
        new = []
        parts = []
        for u in unsq:
            half = u.input[0]
            p = f"{half}/prelu"
            new.append(helper.make_node("PRelu", [half, prelu.input[1]], [p], name=p))
            new.append(helper.make_node("Add", [p, mul.output[0]], [f"{half}/sum"], name=f"{half}/sum"))
            new.append(
                helper.make_node("Unsqueeze", [f"{half}/sum", u.input[1]], [f"{half}/sum5d"], name=u.name)
            )
            parts.append(f"{half}/sum5d")
        new.append(helper.make_node("Concat", parts, [cat.output[0]], name=cat.name, axis=4))
        new.append(helper.make_node("Reshape", [cat.output[0], rs.input[1]], [add.output[0]], name=rs.name))
        drop.update(id(n) for n in (*unsq, cat, rs, prelu, resize, add))
        insert[id(add)] = new
    if not insert:
        return
    nodes = []
    for n in g.node:
        if id(n) in insert:
            nodes.extend(insert[id(n)])
        elif id(n) not in drop:
            nodes.append(n)
    del g.node[:]
    g.node.extend(nodes)
