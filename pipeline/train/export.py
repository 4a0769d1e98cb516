"""``tween export``: both networks to ONNX, plus model.json (what inference needs) and hashes."""

from __future__ import annotations

import json
import os
import sys
import warnings
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from pipeline.atomic import naming, save_torch, write_bytes
from pipeline.data import posebank
from pipeline.data.cache import load_split
from pipeline.data.split import list_clips
from pipeline.data.terms import commercial
from pipeline.errors import TweenError
from pipeline.infer.dna_poses import n_dna_channels
from pipeline.infer.folder import FORMAT, model_hash, read_json_object, read_model_json
from pipeline.networks.generator import Generator, GeneratorConfig
from pipeline.networks.path import PathConfig, PathPredictor
from pipeline.train.generator_training import check_network_size, check_weight_count, read_checkpoint
from pipeline.usd.take import load_takes


def _load(cls, cfg_cls, ckpt: Path, key="model"):
    """The network of a run's checkpoint; TweenError naming it when its config does not
    describe the network its weights are of, or a weight is not a finite number (a run that
    diverged: its export would fill every frame with NaN)."""
    state = read_checkpoint(ckpt, "the run's checkpoint")
    config = state["config"]
    mcfg = config.get("model") if isinstance(config, dict) else None
    if not isinstance(mcfg, dict):
        raise TweenError(f"{ckpt}: the run's checkpoint: its config describes no network (no 'model' table)")
    try:
        if cfg_cls is GeneratorConfig:  # (the switches of retired experiments dropped)
            cfg = GeneratorConfig.saved(mcfg, ckpt)
            # Sized on the meta device first, as `tween train --init` does: a config of width
            # 10**6 or 1,000 levels allocated gigabytes before its weights were compared.
            check_network_size(cfg, state[key], f"{ckpt}: the run's checkpoint")
        else:
            cfg = cfg_cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in mcfg.items()})
            check_weight_count(cls, cfg, state[key], f"{ckpt}: the run's checkpoint")
        net = cls(cfg)
        net.load_state_dict(state[key])
    except (TypeError, ValueError, KeyError, RuntimeError, AttributeError) as e:
        lines = [t.strip() for t in str(e).splitlines() if t.strip() and not t.strip().endswith(":")]
        why = lines[0][:160] if lines else type(e).__name__  # torch's first line is only a heading
        raise TweenError(
            f"{ckpt}: the run's checkpoint: its weights are not those of the network its config describes ({why})"
        ) from None
    bad = [
        n
        for n, t in state[key].items()
        if torch.is_tensor(t) and t.is_floating_point() and not t.isfinite().all()
    ]
    if bad:
        which = f"weights {bad[0]} and {len(bad) - 1} more are" if len(bad) > 1 else f"weight {bad[0]} is"
        raise TweenError(f"{ckpt}: the run's checkpoint: {which} not finite numbers (the run diverged)")
    net.eval()
    return net, cfg, state


def macs_per_frame(net: torch.nn.Module, channels: int, frames: int = 256) -> float:
    """Multiply-accumulates per output frame, counted from every convolution's shapes."""
    total = 0

    def hook(mod, inp, out):
        nonlocal total
        k = mod.kernel_size[0]
        if isinstance(mod, torch.nn.ConvTranspose1d):
            total += inp[0].shape[-1] * mod.in_channels * mod.out_channels * k // mod.groups
        else:
            total += out.shape[-1] * mod.in_channels * mod.out_channels * k // mod.groups

    hooks = [
        m.register_forward_hook(hook)
        for m in net.modules()
        if isinstance(m, torch.nn.Conv1d | torch.nn.ConvTranspose1d)
    ]
    with torch.no_grad():
        net(torch.zeros(1, channels, frames))
    for h in hooks:
        h.remove()
    return total / frames


def export(run_dir: Path, out_dir: Path, name: str, extra: dict | None = None) -> dict:
    """The model folder ``out_dir`` (model ``name``) from a run's checkpoints: the networks in
    ONNX, their torch weights, the pose bank and model.json (``extra``: its inference
    settings); returns model.json's content."""
    # Long because it writes one folder's files in order: generator, path predictor, torch
    # checkpoints, pose bank, then model.json with the hash of them all.
    out_dir.mkdir(parents=True, exist_ok=True)
    gen, gcfg, gstate = _load(Generator, GeneratorConfig, run_dir / "generator.pt")
    files = {}
    x = torch.randn(1, gen.in_channels, 2 * gcfg.multiple)
    args, names = (x,), ["features"]
    axes = {"features": {0: "batch", 2: "frames"}, "residual": {0: "batch", 2: "frames"}}
    if gcfg.dna:  # motion-DNA poses (any number) and a per-window weight (0: none)
        args = (x, torch.randn(1, n_dna_channels(gcfg.n_joints), 3), torch.ones(1, 1))
        names += ["dna", "dna_weight"]
        axes.update(dna={0: "batch", 2: "poses"}, dna_weight={0: "batch"})
    # The ONNX writer's OSError on a full disk names no file; torch's note on Slice folding
    # is nothing to act on.
    with warnings.catch_warnings(), naming(out_dir / "generator.onnx"):
        warnings.filterwarnings("ignore", message="Constant folding - Only steps=1", category=UserWarning)
        torch.onnx.export(
            gen,
            args,
            str(out_dir / "generator.onnx"),
            input_names=names,
            output_names=["residual"],
            dynamic_axes=axes,
            opset_version=17,
            dynamo=False,
        )
    files["generator"] = "generator.onnx"
    meta = {
        "kind": "generator-onnx",  # the family pipeline.infer.api.load_model loads it with
        "name": name,
        "format": FORMAT,
        "fps": 30.0,
        "skeleton": "bandai_skeleton.json",
        "multiple": gcfg.multiple,
        "receptive_field": gcfg.receptive_field(),
        "generator": asdict(gcfg),
        "max_gap": int(gstate["config"].get("gap_end", 90)),
        "train_steps": gstate["step"],
        "train_seconds": round(gstate["elapsed"], 1),
        "parameters": {"generator": sum(p.numel() for p in gen.parameters())},
        "flops_per_frame": {"generator": 2 * macs_per_frame(gen, gen.in_channels)},
    }
    if (run_dir / "path.pt").exists():
        path, pcfg, pstate = _load(PathPredictor, PathConfig, run_dir / "path.pt")
        xp = torch.randn(1, (pcfg.n_joints - 1) * 3, 64)
        with warnings.catch_warnings(), naming(out_dir / "path.onnx"):  # (as the generator's)
            warnings.filterwarnings("ignore", message="Constant folding - Only steps=1", category=UserWarning)
            torch.onnx.export(
                path,
                (xp,),
                str(out_dir / "path.onnx"),
                input_names=["local_positions"],
                output_names=["root_velocity"],
                dynamic_axes={
                    "local_positions": {0: "batch", 2: "frames"},
                    "root_velocity": {0: "batch", 2: "frames"},
                },
                opset_version=17,
                dynamo=False,
            )
        files["path"] = "path.onnx"
        meta["path"] = asdict(pcfg)
        meta["parameters"]["path"] = sum(p.numel() for p in path.parameters())
        meta["flops_per_frame"]["path"] = 2 * macs_per_frame(path, (pcfg.n_joints - 1) * 3)
        meta["path_train_steps"] = pstate["step"]
    # Weights-only torch checkpoints beside the ONNX files: a later run continues from them
    # (`tween train --init <model>/torch/generator.pt`) without the optimiser state.
    (out_dir / "torch").mkdir(exist_ok=True)
    keep = ("model", "config", "step", "elapsed")
    save_torch(_shipped(gstate, keep), out_dir / "torch" / "generator.pt")
    if "path" in files:
        save_torch(_shipped(pstate, keep), out_dir / "torch" / "path.pt")
    meta["files"] = files
    # Padded like training windows (64–128 frames, ending on a key, motion after a target);
    # see OnnxInbetweener._network (models/default/HISTORY.md, Pad layout: the layouts tried).
    meta.update(pad="hold-key", pad_tail=16, min_window=64, feet_anchor=True, feet_orient=True)
    meta.update(extra or {})
    meta.update(data_terms(gstate.get("config", {})))
    bank = _pose_bank(out_dir, gstate.get("config", {}))
    if bank:
        meta["pose_bank"] = bank
    credit = meta.pop("familiar_credit", None)  # --[no-]familiar-credit; None: by the run
    if credit is None:
        # A fine-tune on a studio's takes: nothing measured its lead over the spline on them,
        # so the trusted fill gives it no familiar credit (docs/trust.md, Familiar credit).
        credit = not gstate.get("config", {}).get("data")
    if not credit:  # (absent means true: models exported before the key keep their hash)
        meta["familiar_credit"] = False
    meta["hash"] = model_hash(out_dir, meta)
    write_bytes(out_dir / "model.json", json.dumps(meta, indent=1).encode())
    return meta


#: Paths under this folder (the repository) are written relative to it in exported checkpoints.
REPOSITORY = Path(__file__).resolve().parents[2]


def _shipped(state: dict, keep: tuple[str, ...]) -> dict:
    """The checkpoint's ``keep`` entries, its config's paths inside the repository (``init``,
    ``corpus``: a recipe resolves them) relative to it, so a shipped model folder does not
    carry the path of the machine it was exported on."""
    out = {k: state[k] for k in keep if k in state}
    if isinstance(out.get("config"), dict):
        out["config"] = {k: _relative(v) for k, v in out["config"].items()}
    return out


def _relative(value):
    """``value`` relative to the repository where it is an absolute path inside it."""
    if isinstance(value, str) and value.startswith("/"):
        try:
            return Path(value).resolve().relative_to(REPOSITORY).as_posix()
        except ValueError:  # outside the repository (a studio's takes): the run's own record
            return value
    return value


#: The Bandai Namco dataset's terms (../shared/data/README.md: CC BY-NC 4.0, `*/LICENSE`).
BANDAI_LICENCE = "CC BY-NC 4.0"


def data_terms(config: dict) -> dict:
    """model.json's ``licence`` and ``sources`` (models/README.md) for a run on a corpus: each
    source's licence and hours, and the terms of the model it continued (``--init``), which a
    fine-tune inherits; for a run on a studio's takes (``--data``), those takes (their terms
    are the studio's: not stated) and the inherited terms; for a run on the train split, its
    CC BY-NC 4.0. ``commercial`` only where every one of those terms is known to allow it."""
    if config.get("corpus"):
        from pipeline.train.corpus import prepared

        try:
            _, _, manifest = prepared(config["corpus"], progress=False)
        except TweenError as e:  # a host without the corpus's data: the card must say it
            print(f"tween: warning: no licence recorded in model.json ({e})", file=sys.stderr)
            return {}
        sources = [{"name": f"{manifest['name']}/{s['name']} ({s['path']})", "licence": s["licence"],
                    "frames": s["frames"], "fps": manifest["fps"], "hours": s["hours"], "weight": s["weight"],
                    "use": "trained"} for s in manifest["sources"]]  # fmt: skip
    elif config.get("data"):  # a fine-tune must not drop the terms of the model it continued
        sources = [{"name": f"takes of {config['data']}", "licence": "not stated (the studio's own takes)",
                    "use": "trained"}]  # fmt: skip
    else:  # the train split (read from ../shared, or packed: --data-pack)
        sources = [{"name": "Bandai Namco Research Motion Dataset 1 and 2, train split", "licence": BANDAI_LICENCE,
                    "use": "trained"}]  # fmt: skip
    init = Path(config["init"]) if config.get("init") else None
    folder = init if init is None or init.is_dir() else init.parent.parent  # <model>/torch/generator.pt
    if init is not None:
        card = folder / "model.json"  # a run folder given as --init holds none: terms not stated
        # A damaged card (a pipe, /dev/zero, deep JSON) is one line naming it, not a hang.
        given = read_json_object(card, "model.json") if os.path.lexists(card) else {}
        if isinstance(given.get("name"), str):
            sources.append({"name": given["name"], "licence": given.get("licence", "not stated"),
                            "use": f"inherited: initialised from {init}"})  # fmt: skip
        else:
            sources.append(
                {"name": str(init), "licence": "not stated", "use": "inherited: initialised from it"}
            )
    licences = list(dict.fromkeys(s["licence"] for s in sources))
    return {"licence": "; ".join(licences), "commercial": commercial(licences), "sources": sources}


def _pose_bank(out_dir: Path, config: dict) -> str | None:
    """The pose bank beside the networks (pipeline.data.posebank: what the trusted fill
    compares a shot's keys with): the train split's poses, and for a fine-tune on a studio's
    takes (``tween train --data``) half of them the takes'. None where the data cannot be read,
    and for a network with relative pose inputs (``--delta``: a posture offset is no new pose
    to it, so absolute poses say nothing of what it knows; docs/trust.md)."""
    if (config.get("model") or {}).get("delta"):
        return None
    try:
        if config.get("corpus"):  # the corpus names its own sources (Bandai's among them or not)
            from pipeline.train.corpus import corpus_clips

            sets = [(f"corpus {config['corpus']}", corpus_clips(config["corpus"]))]
        else:
            sets = [("bandai_namco train split", load_split("train"))]
        if config.get("data") and not config.get("corpus"):
            sets.append(
                (f"takes of {config['data']}", load_takes(config["data"], config.get("data_include")))
            )
    except (OSError, ValueError, TweenError) as e:
        print(f"tween: warning: {out_dir}: no pose bank written ({e}); its fills trust the network "
              "as if every shot were its own data", file=sys.stderr)  # fmt: skip
        return None
    each = posebank.POSES // len(sets)
    bank = np.concatenate([posebank.build(c.rotations, c.roots, each) for _, c in sets])
    source = "; ".join(f"{name}: {min(each, len(c.rotations))} poses" for name, c in sets) + ", seed 0"
    with naming(out_dir / "pose_bank.npz"):
        posebank.save(out_dir / "pose_bank.npz", bank, source)
    return "pose_bank.npz"


def _gap(a: np.ndarray, b: np.ndarray, random: bool) -> float:
    """|a − b| at its largest, over max(1, |b|) at its largest for random inputs."""
    d = float(np.abs(a - b).max())
    if not np.isfinite(d):  # max() would drop a NaN and pass the export
        return float("inf")
    return d / max(1.0, float(np.abs(b).max())) if random else d


def verify(run_dir: Path, model_dir: Path, seed: int = 0) -> float:
    """How far onnxruntime and torch disagree, for every exported network: the largest
    difference on real inputs (an eval clip's features), and on random inputs the largest
    difference over max(1, the largest output), since their outputs reach ±100 and float32
    then rounds at ~1e-5 in either runtime alone."""
    import onnxruntime as ort

    from pipeline.data.skeletons import bandai_skeleton
    from pipeline.infer.features import build_features, feature_options
    from pipeline.motion.bvh import read_bvh
    from pipeline.train.path_training import path_inputs

    meta = read_model_json(model_dir)
    gen, gcfg, _ = _load(Generator, GeneratorConfig, run_dir / "generator.pt")
    rng = np.random.default_rng(seed)
    skel = bandai_skeleton()
    inputs = [(rng.normal(size=(2, gen.in_channels, 96)).astype(np.float32), True)]  # (x, random)
    try:
        # The longest of the first 40 eval clips (the first few are under 2 s), at most 256 frames.
        m = max(map(read_bvh, list_clips("eval")[:40]), key=len).continuous()
        n = (min(len(m), 256) // gcfg.multiple) * gcfg.multiple
        keys = np.arange(0, n, 8)
        keys[-1] = n - 1
        feats, ctx = build_features(
            m.rotations[None, :n], m.root_positions[None, :n], keys, skel, **feature_options(asdict(gcfg))
        )
        inputs.append((feats, False))
    except FileNotFoundError:
        ctx = None
    worst = 0.0
    sess = ort.InferenceSession(
        str(model_dir / meta["files"]["generator"]), providers=["CPUExecutionProvider"]
    )
    with torch.no_grad():
        for x, random in inputs:
            feeds = {"features": x}
            if gcfg.dna:  # a random DNA of 5 poses, on for the first window only
                feeds["dna"] = rng.normal(size=(len(x), n_dna_channels(gcfg.n_joints), 5)).astype(np.float32)
                feeds["dna_weight"] = (np.arange(len(x))[:, None] == 0).astype(np.float32)
            a = sess.run(None, feeds)[0]
            b = gen(*(torch.from_numpy(v) for v in feeds.values())).numpy()
            worst = max(worst, _gap(a, b, random))
        if "path" in meta["files"]:
            path, _, _ = _load(PathPredictor, PathConfig, run_dir / "path.pt")
            ps = ort.InferenceSession(
                str(model_dir / meta["files"]["path"]), providers=["CPUExecutionProvider"]
            )
            xs = [(rng.normal(size=(2, 60, 64)).astype(np.float32), True)]
            if ctx is not None:
                xs.append((path_inputs(ctx["crot"], ctx["croot"], skel), False))
            for x, random in xs:
                a = ps.run(None, {"local_positions": x})[0]
                worst = max(worst, _gap(a, path(torch.from_numpy(x)).numpy(), random))
    return worst
