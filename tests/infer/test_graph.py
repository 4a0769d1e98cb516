"""The generator's opt-in load-time rewrite (pipeline/infer/graph.py): the same network in 2D
for onnxruntime's NCHWc kernels, residual scales folded, ConvTranspose as two convolutions;
within float32 reordering of the plain graph, and None (the plain graph) where it cannot
be made or checked. Default fills run the graph as exported, bitwise."""

import os
import subprocess
import sys

import numpy as np
import pytest

from pipeline.data.skeletons import bandai_skeleton
from pipeline.infer.features import adapter_free_graph, build_features, n_input_channels
from pipeline.infer.graph import TOLERANCE, check_graph, fast_graph
from pipeline.infer.model import OnnxInbetweener
from pipeline.motion.bvh import read_bvh

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
from onnx import TensorProto, helper, numpy_helper  # noqa: E402

SKEL = bandai_skeleton()
J = len(SKEL)
RNG = np.random.default_rng(7)


@pytest.fixture(scope="module")
def clip(bandai_clip):
    m = read_bvh(bandai_clip).continuous()
    return m.rotations[None, :150].astype(np.float32), m.root_positions[None, :150].astype(np.float32)


def _run(graph, x):
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = opts.inter_op_num_threads = 1
    return ort.InferenceSession(graph, opts, providers=["CPUExecutionProvider"]).run(None, {"features": x})[0]


def _toy(c: float = 0.7, extra=None, proj: bool = False) -> bytes:
    """A small generator-shaped graph: conv + affine + PReLU + scaled residual, a stride-2
    down block with an average-pooled skip, an up block (ConvTranspose, upsampling written
    as Unsqueeze/Tile/Reshape), an output conv."""
    C = 16
    inits = {
        "w0": RNG.normal(size=(C, 8, 3)) * 0.3,
        "b0": RNG.normal(size=C),
        "s0": RNG.uniform(0.5, 2, size=(1, C, 1)),
        "t0": RNG.normal(size=(1, C, 1)),
        "a0": RNG.uniform(0, 0.3, size=(C, 1)),
        "c": np.array(c),
        "k": np.array(0.6),
        "wd": RNG.normal(size=(C, C, 4)) * 0.3,
        "bd": RNG.normal(size=C),
        "ad": RNG.uniform(0, 0.3, size=(C, 1)),
        "wu": RNG.normal(size=(C, C, 4)) * 0.3,
        "bu": RNG.normal(size=C),
        "su": RNG.uniform(0.5, 2, size=(1, C, 1)),
        "tu": RNG.normal(size=(1, C, 1)),
        "au": RNG.uniform(0, 0.3, size=(C, 1)),
        "wp": RNG.normal(size=(C, C, 1)) * 0.3,
        "bp": RNG.normal(size=C),
        "wo": RNG.normal(size=(5, C, 3)) * 0.3,
        "bo": RNG.normal(size=5),
    }
    inits = {k: np.asarray(v, np.float32) for k, v in inits.items()}
    inits |= {
        "ax3": np.array([3]),
        "rep": np.array([1, 1, 1, 2]),
        "z": np.array([0]),
        "two": np.array([2]),
        "m1": np.array([-1]),
        "s_start": np.array([0]),
        "s_end": np.array([8]),
        "s_axis": np.array([1]),
    }
    n = helper.make_node
    nodes = [
        n("Slice", ["features", "s_start", "s_end", "s_axis"], ["xs"]),
        n("Conv", ["xs", "w0", "b0"], ["h0"], kernel_shape=[3], pads=[1, 1]),
        n("Mul", ["h0", "s0"], ["h1"]),
        n("Add", ["h1", "t0"], ["h2"]),
        n("PRelu", ["h2", "a0"], ["h3"]),
        n("Mul", ["h3", "c"], ["x1"]),
        n("Conv", ["x1", "wd", "bd"], ["d0"], kernel_shape=[4], pads=[1, 1], strides=[2]),
        n("PRelu", ["d0", "ad"], ["d1"]),
        n("Mul", ["d1", "c"], ["d2"]),
        n("AveragePool", ["x1"], ["p0"], kernel_shape=[2], strides=[2]),
        n("Mul", ["p0", "k"], ["p1"]),
        n("Add", ["d2", "p1"], ["x2"]),
        n("ConvTranspose", ["x2", "wu", "bu"], ["u0"], kernel_shape=[4], pads=[1, 1], strides=[2]),
        n("Mul", ["u0", "su"], ["u1"]),
        n("Add", ["u1", "tu"], ["u2"]),
        n("PRelu", ["u2", "au"], ["u3"]),
        n("Mul", ["u3", "c"], ["u4"]),
        n("Unsqueeze", ["x2", "ax3"], ["r0"]),
        n("Tile", ["r0", "rep"], ["r1"]),
        n("Shape", ["r1"], ["r2"]),
        n("Slice", ["r2", "z", "two", "z"], ["r3"]),
        n("Concat", ["r3", "m1"], ["r4"], axis=0),
        n("Reshape", ["r1", "r4"], ["r5"]),
        *([n("Conv", ["r5", "wp", "bp"], ["r5p"], kernel_shape=[1])] if proj else []),
        n("Mul", ["r5p" if proj else "r5", "k"], ["r6"]),
        n("Add", ["u4", "r6"], ["x3"]),
        n("Add", ["x3", "x1"], ["x4"]),
        n("Conv", ["x4", "wo", "bo"], ["residual"], kernel_shape=[3], pads=[1, 1]),
        *(extra or []),
    ]
    g = helper.make_graph(
        nodes,
        "toy",
        [helper.make_tensor_value_info("features", TensorProto.FLOAT, ["batch", 8, "frames"])],
        [helper.make_tensor_value_info("residual", TensorProto.FLOAT, ["batch", 5, "frames"])],
        [numpy_helper.from_array(v, k) for k, v in inits.items()],
    )
    return helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)]).SerializeToString()


def _ops(graph: bytes) -> set:
    return {n.op_type for n in onnx.load_from_string(graph).graph.node}


@pytest.mark.parametrize("proj", [False, True])
def test_the_rewrite_is_the_same_network_in_2d(proj):
    plain = _toy(proj=proj)
    fast = fast_graph(plain)
    assert fast is not None
    ops = _ops(fast)
    # No ConvTranspose, no Tile; the upsampled skip is summed before the interleave (no Resize).
    assert not {"ConvTranspose", "Tile", "Resize"} & ops
    # The positive scale after each PReLU went into the convolutions: two Muls are left
    # (the residual weights on the skips).
    assert sum(n.op_type == "Mul" for n in onnx.load_from_string(fast).graph.node) == 2
    for x in (RNG.normal(size=(2, 8, 96)), RNG.normal(size=(1, 8, 32)) * 10):
        x = x.astype(np.float32)
        a, b = _run(plain, x), _run(fast, x)
        assert a.shape == b.shape
        assert np.abs(a - b).max() <= 1e-6 * np.abs(a).max()
    assert check_graph(plain, fast) is not None
    # Without the ConvTranspose split the upsampling is a nearest Resize.
    assert "Resize" in _ops(fast_graph(plain, split_transposed=False))


def test_each_rewrite_on_its_own_and_what_is_not_folded():
    plain = _toy(c=-0.7)  # a negative scale does not commute with PReLU: left as it is
    x = RNG.normal(size=(1, 8, 64)).astype(np.float32)
    for kw in ({"nchwc": False}, {"fold": False}, {"split_transposed": False}, {}):
        fast = fast_graph(plain, **kw)
        assert fast is not None, kw
        a, b = _run(plain, x), _run(fast, x)
        assert np.abs(a - b).max() <= 1e-6 * np.abs(a).max(), kw
    assert (
        sum(n.op_type == "Mul" for n in onnx.load_from_string(fast_graph(plain)).graph.node) == 7
    )  # (and the affines)


def test_unknown_ops_or_a_failed_check_give_the_plain_graph():
    # An op the rewrite does not know (a Transpose of the frames) -> None.
    extra = [helper.make_node("Transpose", ["residual"], ["t"], perm=[0, 2, 1])]
    assert fast_graph(_toy(extra=extra)) is None
    assert fast_graph(b"not a graph") is None
    # A rewrite whose output differs is refused by the check.
    plain = _toy()
    m = onnx.load_from_string(fast_graph(plain))
    for t in m.graph.initializer:
        if t.name.startswith("wo"):
            w = numpy_helper.to_array(t).copy()
            w[0] += 1.0
            t.CopyFrom(numpy_helper.from_array(w, t.name))
    assert check_graph(plain, m.SerializeToString()) is None
    assert TOLERANCE <= 1e-5


def test_the_default_generator_is_rewritten_and_matches_on_real_features(clip):
    rot, root = clip
    path = "models/default/generator.onnx"
    lean = adapter_free_graph(path, J)
    if lean is None:
        pytest.skip("no adapter-free graph")
    for graph in (lean, path):
        assert fast_graph(graph) is not None
    n = 128
    feats, _ = build_features(
        rot[:, :n], root[:, :n], np.r_[0:n:10, n - 1], SKEL, key_adapter=True, adapter=False
    )
    feats = np.ascontiguousarray(feats[:, : n_input_channels(J)])
    a, b = _run(lean, feats), _run(fast_graph(lean), feats)
    assert np.abs(a - b).max() <= TOLERANCE * np.abs(a).max()


def test_the_default_fill_is_bitwise_the_graph_as_exported(clip, monkeypatch):
    """The rewrite is opt-in: a default fill is the exported file's own, through a plain
    onnxruntime session (default options) on the whole graph, bit for bit."""
    monkeypatch.delenv("TWEEN_FAST_GRAPH", raising=False)
    rot, root = clip
    keys = np.r_[np.arange(0, 149, 8), 149]
    shipped, reference = OnnxInbetweener("models/default"), OnnxInbetweener("models/default")
    assert shipped.fast_graph is False
    reference.skip_adapter = False
    reference._sessions["generator"] = ort.InferenceSession(
        "models/default/generator.onnx", providers=["CPUExecutionProvider"]
    )
    mask = np.ones((len(keys), J + 1), bool)
    mask[4, :J] = False
    noise = np.random.default_rng(3).normal(size=(1, 8))
    for args in ((keys,), (keys, noise), (keys, None, mask)):
        (qa, ra), (qb, rb) = shipped.fill_batch(rot, root, *args), reference.fill_batch(rot, root, *args)
        assert np.array_equal(qa, qb) and np.array_equal(ra, rb)
    # ... while the opt-in rewrite is not (it sums in another order).
    fast = OnnxInbetweener("models/default")
    fast.fast_graph = True
    assert not np.array_equal(fast.fill_batch(rot, root, keys)[0], shipped.fill_batch(rot, root, keys)[0])


def test_the_rewrite_is_opt_in_through_the_environment():
    code = "from pipeline.infer.model import OnnxInbetweener as M; print(M.fast_graph)"
    for value, want in ((None, "False"), ("0", "False"), ("1", "True")):
        env = {k: v for k, v in os.environ.items() if k != "TWEEN_FAST_GRAPH"}
        if value is not None:
            env["TWEEN_FAST_GRAPH"] = value
        out = subprocess.run(
            [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
        )
        assert out.stdout.strip() == want


def test_fills_with_and_without_the_rewrite(clip):
    rot, root = clip
    keys = np.r_[np.arange(0, 149, 8), 149]
    fast, plain = OnnxInbetweener("models/default"), OnnxInbetweener("models/default")
    fast.fast_graph, plain.fast_graph = True, False
    mask = np.ones((len(keys), J + 1), bool)
    mask[4, :J] = False
    for jk in (None, mask):
        (qa, ra), (qb, rb) = (
            fast.fill_batch(rot, root, keys, None, jk),
            plain.fill_batch(rot, root, keys, None, jk),
        )
        dq = np.minimum(np.abs(qa - qb).max(-1), np.abs(qa + qb).max(-1))
        assert dq.max() < 1e-4 and np.quantile(dq, 0.99) < 1e-5
        assert np.abs(ra - rb).max() <= 1e-6 * np.abs(rb).max() + 1e-6
        # Keys stay exact either way.
        full = keys[mask.all(1)] if jk is not None else keys
        assert np.array_equal(ra[:, full], rb[:, full])
