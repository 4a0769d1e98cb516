"""``tween bench --speed``: how far a fill is from the core's own arithmetic peak.

One run measures, side by side:

(a) the core's single-thread sgemm peak: a large float32 matmul in numpy, in a subprocess
    limited to one BLAS thread (threadpoolctl where installed, and the OpenBLAS/OMP thread
    variables), with ``OPENBLAS_CORETYPE`` / ``OPENBLAS_L2_SIZE`` unset in that process only
    (set on some machines for older OpenBLAS builds, they pin a slower kernel; the kernel
    threadpoolctl reports is printed);
(b) the generator's FLOPs per frame, counted from the ONNX graph's Conv / ConvTranspose /
    MatMul / Gemm weight shapes and the time resolution each runs at, with and without the
    partial-key adapter (model.json's ``flops_per_frame`` where the ``onnx`` package is
    missing);
(c) a fill of ``frames`` frames (keys every 10) end to end in the in-betweener, median of
    ``repeats`` runs, broken down into the network (onnxruntime), the features, the
    post-processing (key matching, foot locking) and the rest (padding, decoding), for the
    shipped path (the generator without its adapter on full keys) and the whole graph;
(d) the network alone under each onnxruntime graph-optimisation level (1 intra-op thread).

The ratio printed is the fill's time over the time its network FLOPs take at the peak.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from pipeline.bench.outputs import write_outputs
from pipeline.data.split import shared_data_dir
from pipeline.errors import TweenError

_PEAK_CODE = r"""
import json, sys, time
import numpy as np
n, repeats = int(sys.argv[1]), int(sys.argv[2])
try:
    from threadpoolctl import threadpool_info, threadpool_limits
    limits = threadpool_limits(1)
    info = [(i.get("internal_api"), i.get("architecture"), i.get("num_threads")) for i in threadpool_info()]
except ImportError:
    info = None
a = np.random.default_rng(0).standard_normal((n, n), dtype=np.float32)
b = np.random.default_rng(1).standard_normal((n, n), dtype=np.float32)
a @ b
best = float("inf")
for _ in range(repeats):
    t = time.perf_counter()
    a @ b
    best = min(best, time.perf_counter() - t)
print(json.dumps({"gflops": 2 * n**3 / best / 1e9, "n": n, "seconds": best, "blas": info}))
"""


def sgemm_peak(n: int = 2048, repeats: int = 5) -> dict:
    """GFLOP/s of an n×n float32 matmul on one thread, best of ``repeats`` (a subprocess)."""
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE")}
    env.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    out = subprocess.run(
        [sys.executable, "-c", _PEAK_CODE, str(n), str(repeats)],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    res = json.loads(out.stdout.strip().splitlines()[-1])
    blas = res.pop("blas")
    res["kernel"] = (
        "threadpoolctl not installed"
        if blas is None
        else ", ".join(
            f"{api} {arch} ({threads} thread{'s' * (threads != 1)})" for api, arch, threads in blas
        )
    )
    return res


def graph_flops(path: str | Path, frames: int = 256) -> dict | None:
    """FLOPs per input frame of an ONNX graph (2 per multiply-accumulate of its Conv,
    ConvTranspose, MatMul and Gemm nodes), in total and for the nodes of the partial-key
    adapter (``/adapter/``); None without the ``onnx`` package.

    The graph runs once on ``frames`` frames of zeros with every such node's input and
    output exposed, so each node's frame count is the one it really computes (shape
    inference cannot follow the graph's shape arithmetic); a Conv then costs
    out_frames · Cout · Cin/g · k multiply-accumulates, a ConvTranspose in_frames · Cin ·
    Cout/g · k, as ``pipeline.train.export.macs_per_frame`` counts them in torch."""
    try:
        import onnx
        import onnxruntime as ort
        from onnx import numpy_helper
    except ImportError:
        return None
    model = onnx.load(str(path))
    g = model.graph
    weights = {t.name: numpy_helper.to_array(t).shape for t in g.initializer}
    nodes = [n for n in g.node if n.op_type in ("Conv", "ConvTranspose", "MatMul", "Gemm")]
    nodes = [n for n in nodes if len(n.input) > 1 and n.input[1] in weights]
    have = {o.name for o in g.output}
    probe = sorted({n.input[0] for n in nodes} | {n.output[0] for n in nodes} - have)
    for name in probe:
        g.output.append(onnx.helper.make_tensor_value_info(name, onnx.TensorProto.FLOAT, None))
    feeds = {}
    for i in g.input:
        if i.name in weights:
            continue
        dims = [d.dim_value for d in i.type.tensor_type.shape.dim]
        dims = [v or (frames if k == len(dims) - 1 else 1) for k, v in enumerate(dims)]  # (batch, C, frames)
        feeds[i.name] = np.zeros(dims, np.float32)
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    shapes = dict(
        zip([o.name for o in sess.get_outputs()], [a.shape for a in sess.run(None, feeds)], strict=True)
    )
    total = adapter = 0.0
    for n in nodes:
        w = weights[n.input[1]]
        if n.op_type == "Conv":  # w (Cout, Cin/g, k...), per output frame
            macs = int(np.prod(w)) * shapes[n.output[0]][-1]
        elif n.op_type == "ConvTranspose":  # w (Cin, Cout/g, k...), per input frame
            macs = int(np.prod(w)) * shapes[n.input[0]][-1]
        else:  # MatMul / Gemm: every row of the input
            macs = int(np.prod(w)) * int(np.prod(shapes[n.input[0]][:-1]))
        total += 2 * macs / frames
        if n.name.startswith("/adapter/"):
            adapter += 2 * macs / frames
    return {"total": total, "adapter": adapter, "source": "ONNX graph"}


def demo_shot(frames: int, keys_every: int = 10):
    """(rot (1, N, J, 4), root (1, N, 3), keys): the Bandai walk of the tests looped to
    ``frames`` frames (moving on each loop), or where the data is missing a synthetic walk."""
    from pipeline.data.skeletons import bandai_skeleton

    J = len(bandai_skeleton())
    try:
        from pipeline.motion.bvh import read_bvh

        clip = shared_data_dir() / "bandai_namco" / "dataset-2" / "dataset-2_walk_active_002.bvh.gz"
        m = read_bvh(clip).continuous()
        rot, root = m.rotations.astype(np.float32), m.root_positions.astype(np.float32)
        reps = -(-frames // len(rot))
        step = (root[-1] - root[0]) * np.array([1, 0, 1], np.float32)
        rot = np.concatenate([rot] * reps)[:frames]
        root = np.concatenate([root + i * step for i in range(reps)])[:frames]
    except (OSError, ValueError):
        from pipeline.motion.rotations import batch_rotvec_to_quat

        t = np.arange(frames)[:, None, None] / 30.0
        phase = np.random.default_rng(0).uniform(0, 2 * np.pi, size=(1, J, 3))
        rot = batch_rotvec_to_quat(0.3 * np.sin(2 * np.pi * t + phase)).astype(np.float32)
        root = np.stack([120.0 * t[:, 0, 0], 90 + 3 * np.sin(4 * np.pi * t[:, 0, 0]), 0 * t[:, 0, 0]], -1)
        root = root.astype(np.float32)
    keys = np.r_[np.arange(0, frames - 1, keys_every), frames - 1]
    return rot[None], root[None], keys


class _Timed:
    """Wraps a callable, adding its wall time to ``spent[name]``."""

    def __init__(self, fn, spent: dict, name: str):
        self.fn, self.spent, self.name = fn, spent, name

    def __call__(self, *a, **kw):
        t = time.perf_counter()
        try:
            return self.fn(*a, **kw)
        finally:
            self.spent[self.name] = self.spent.get(self.name, 0.0) + time.perf_counter() - t


def time_fill(model, rot, root, keys, repeats: int = 5) -> dict:
    """Median wall time of ``model.fill_batch`` over ``repeats`` runs (after one warm-up), its
    CPU time (the process's: on shared cores wall time also counts waiting for one), and the
    median wall time of each part: network, features, post (match_keys + lock_feet), other."""
    import pipeline.infer.generator_onnx as mod

    sess = model.session("generator")
    spent: dict = {}
    run = sess.run
    patched = {name: getattr(mod, name) for name in ("build_features", "match_keys", "lock_feet")}
    runs = []
    try:
        sess.run = _Timed(run, spent, "network")
        mod.build_features = _Timed(patched["build_features"], spent, "features")
        mod.match_keys = _Timed(patched["match_keys"], spent, "post")
        mod.lock_feet = _Timed(patched["lock_feet"], spent, "post")
        out = model.fill_batch(rot, root, keys)  # warm-up (sessions, caches)
        for _ in range(repeats):
            spent.clear()
            t, c = time.perf_counter(), time.process_time()
            model.fill_batch(rot, root, keys)
            total, cpu = time.perf_counter() - t, time.process_time() - c
            parts = {k: spent.get(k, 0.0) for k in ("network", "features", "post")}
            parts["other"] = total - sum(parts.values())
            runs.append({"total": total, "cpu": cpu, **parts})
    finally:
        for name, fn in patched.items():
            setattr(mod, name, fn)
        del sess.run
    med = {k: float(np.median([r[k] for r in runs])) for k in runs[0]}
    return {"median": med, "runs": runs, "output": out}


def time_levels(path: str | Path | bytes, feats: np.ndarray, repeats: int = 5, ref=None) -> list[dict]:
    """The generator graph (file or bytes) alone on ``feats`` under each onnxruntime
    graph-optimisation level, 1 intra-op thread: median seconds, and how far the output is
    from ``ref`` (default: its own under ORT_ENABLE_ALL, the first level run)."""
    import onnxruntime as ort

    L = ort.GraphOptimizationLevel
    rows = []
    for level in (L.ORT_ENABLE_ALL, L.ORT_ENABLE_EXTENDED, L.ORT_ENABLE_BASIC, L.ORT_DISABLE_ALL):
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = opts.inter_op_num_threads = 1
        opts.graph_optimization_level = level
        sess = ort.InferenceSession(
            path if isinstance(path, bytes) else str(path), opts, providers=["CPUExecutionProvider"]
        )
        out = sess.run(None, {"features": feats})[0]
        ts = []
        for _ in range(repeats):
            t = time.perf_counter()
            sess.run(None, {"features": feats})
            ts.append(time.perf_counter() - t)
        ref = out if ref is None else ref
        rows.append(
            {
                "level": level.name,
                "seconds": float(np.median(ts)),
                "max_diff": float(np.abs(out - ref).max()),
                "bitwise": bool(np.array_equal(out, ref)),
            }
        )
    return rows


def network_levels(shipped, gen_path: Path, lean_graph: bytes | None, shot, repeats: int) -> tuple[list, int]:
    """The generator alone on the demo ``shot``'s padded window (rotations, roots, keys)
    under each onnxruntime graph-optimisation level, the whole graph and (``lean_graph``)
    the graph without the adapter: (rows of :func:`time_levels`, the padded frames)."""
    from pipeline.infer.features import build_features, feature_options, n_input_channels

    rot, root, keys = shot
    frames = rot.shape[1]
    mult = int(shipped.meta["multiple"])
    n_pad = -(-max(frames + shipped.pad_tail, shipped.min_window) // mult) * mult
    pad = np.r_[np.arange(frames), np.full(n_pad - frames, frames - 1)]
    opts = feature_options(shipped.meta.get("generator", {}))
    feats, _ = build_features(
        rot[:, pad], root[:, pad], np.r_[keys, n_pad - 1], shipped.skeleton, None, **opts
    )
    levels = time_levels(gen_path, feats, repeats)
    if lean_graph:
        import onnxruntime as ort

        ref = ort.InferenceSession(str(gen_path), providers=["CPUExecutionProvider"]).run(
            None, {"features": feats}
        )[0]
        lean_feats = np.ascontiguousarray(feats[:, : n_input_channels(len(shipped.skeleton))])
        for row in time_levels(lean_graph, lean_feats, repeats, ref):
            row["level"] += " (adapter skipped)"
            levels.append(row)
    return levels, int(n_pad)


def check_speed_model(name: str) -> tuple[Path, dict]:
    """(folder, its checked model.json) of the human network model ``name`` the speed bench
    times; a one-line TweenError naming ``--methods`` or the file where it cannot."""
    from pipeline.infer.api import DEFAULT_KIND, RIG_FILE, folder_kind, model_folder
    from pipeline.infer.folder import read_model_json

    found = model_folder(name)
    if found is None:
        raise TweenError(f"--methods {name}: no such model (a folder with model.json, or one under models/)")
    folder, file = found
    if file == RIG_FILE:
        raise TweenError(
            f"--methods {name}: {folder} is a per-rig model (rig.json); --speed times a human model"
        )
    kind = folder_kind(folder)
    if kind != DEFAULT_KIND:
        raise TweenError(
            f"--methods {name}: {folder} is a {kind!r} model; --speed times a {DEFAULT_KIND!r} network's fill"
        )
    meta = read_model_json(folder)  # a damaged model.json is one line naming it
    gen = folder / meta["files"]["generator"]
    if not gen.is_file():
        raise TweenError(f"{gen}: missing (the generator {folder / 'model.json'} names)")
    return folder, meta


def run_speed(
    model_name: str = "default",
    frames: int = 4096,
    repeats: int = 5,
    out: Path | None = None,
    peak_n: int = 2048,
) -> str:
    """The speed benchmark; returns its Markdown (and writes speed.json / speed.md to ``out``)."""
    from pipeline.infer.features import adapter_free_graph
    from pipeline.infer.generator_onnx import OnnxInbetweener

    folder, meta = check_speed_model(model_name)
    gen_path = folder / meta["files"]["generator"]
    shipped = OnnxInbetweener(folder)
    peak = sgemm_peak(peak_n, repeats)
    counted = graph_flops(gen_path)
    if counted is None:
        fpf = float(shipped.meta.get("flops_per_frame", {}).get("generator", 0.0))
        counted = {"total": fpf, "adapter": 0.0, "source": "model.json (onnx not installed)"}
    rot, root, keys = demo_shot(frames)
    whole = OnnxInbetweener(folder)
    whole.skip_adapter = False
    lean_graph = adapter_free_graph(gen_path, len(shipped.skeleton), 2 * int(shipped.meta["multiple"]))
    rows = []
    fills = {}
    lean_fpf = counted["total"] - (counted["adapter"] if lean_graph else 0.0)
    lean_name = "shipped: graph as exported (adapter skipped)" if lean_graph else "shipped: graph as exported"
    for name, model, fpf in (
        (lean_name, shipped, lean_fpf),
        ("whole graph as exported (adapter on zeros)", whole, counted["total"]),
    ):
        res = time_fill(model, rot, root, keys, repeats)
        fills[name] = res.pop("output")
        at_peak = fpf * frames / (peak["gflops"] * 1e9)
        rows.append({"path": name, "flops_per_frame": fpf, "at_peak_s": at_peak, **res})
    (q0, r0), (q1, r1) = (fills[r["path"]] for r in rows)
    same = {"max_abs_diff": float(max(np.abs(q0 - q1).max(), np.abs(r0 - r1).max()))}
    levels, n_pad = network_levels(shipped, gen_path, lean_graph, (rot, root, keys), repeats)
    report = {
        "frames": frames,
        "keys_every": 10,
        "repeats": repeats,
        "sgemm_peak": peak,
        "generator_flops_per_frame": counted,
        "fills": [{k: v for k, v in r.items() if k != "runs"} | {"runs": r["runs"]} for r in rows],
        "shipped_vs_whole_graph": same,
        "network_by_ort_level": levels,
        "padded_frames": n_pad,
    }
    md = speed_markdown(report)
    if out is not None:
        write_outputs(Path(out), {"speed.json": json.dumps(report, indent=1), "speed.md": md})
    return md


def speed_markdown(rep: dict) -> str:
    peak = rep["sgemm_peak"]
    fl = rep["generator_flops_per_frame"]
    lines = [
        f"**Fill speed**: {rep['frames']} frames, keys every {rep['keys_every']}, one core "
        f"(1 onnxruntime thread), median of {rep['repeats']}.",
        "",
        f"sgemm peak: {peak['gflops']:.1f} GFLOP/s ({peak['n']}² float32 matmul, 1 thread; {peak['kernel']}). "
        f"Generator: {fl['total'] / 1e6:.2f} MFLOP/frame, {(fl['total'] - fl['adapter']) / 1e6:.2f} without "
        f"the partial-key adapter ({fl['source']}).",
        "",
        "| path | MFLOP/frame | at peak (s) | fill (s) | ratio | CPU (s) | CPU ratio | network | features | post | other |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rep["fills"]:
        m = r["median"]
        lines.append(
            f"| {r['path']} | {r['flops_per_frame'] / 1e6:.2f} | {r['at_peak_s']:.4f} | {m['total']:.4f} "
            f"| **{m['total'] / r['at_peak_s']:.2f}×** | {m['cpu']:.4f} | {m['cpu'] / r['at_peak_s']:.2f}× "
            f"| {m['network']:.4f} | {m['features']:.4f} "
            f"| {m['post']:.4f} | {m['other']:.4f} |"
        )
    lines += [
        "",
        f"Shipped vs whole graph: max |Δ| {rep['shipped_vs_whole_graph']['max_abs_diff']:.3g} (the same fills).",
        "",
        f"Network alone by onnxruntime graph optimisation ({rep['padded_frames']} padded frames):",
        "",
        "| level | network (s) | max Δ vs ENABLE_ALL | bitwise |",
        "|---|---|---|---|",
    ]
    for r in rep["network_by_ort_level"]:
        lines.append(
            f"| {r['level']} | {r['seconds']:.4f} | {r['max_diff']:.3g} | {'yes' if r['bitwise'] else 'no'} |"
        )
    return "\n".join(lines) + "\n"
