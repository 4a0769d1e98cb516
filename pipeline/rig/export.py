"""Exporting a trained per-rig model: one ONNX generator per level, ``rig.json``, the card.

Each level's graph is ``out = g(up + z) + up`` with inputs ``up`` (1, F0, L) and ``z``
(1, 1, L) and a dynamic length L; upsampling between levels happens in numpy at inference
(:func:`pipeline.rig.represent.resample_linear`, the same formula as torch's).
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np

from pipeline.atomic import naming, write_bytes
from pipeline.data.terms import commercial
from pipeline.infer.folder import files_hash
from pipeline.rig.source import portable_path
from pipeline.rig.train import Trainer

CARD = "MODEL_CARD.md"


def choose_legs(parents, contacts: list[int]) -> list[int]:
    """Contact joints the two-bone foot IK can pull: the chain (grandparent, parent, joint)
    must not start at the root or at a branching joint (turning it would move other limbs),
    and at most one joint per chain (the one nearest the body) is used."""
    parents = np.asarray(parents)

    def ancestors(j):
        out = []
        while parents[j] >= 0:
            j = int(parents[j])
            out.append(j)
        return out

    picked: list[int] = []
    for j in sorted(contacts, key=lambda c: len(ancestors(c))):
        p = parents[j]
        g = parents[p] if p >= 0 else -1
        if p < 0 or g < 0 or parents[g] < 0:
            continue
        if sum(1 for q in parents if q == g) != 1 or sum(1 for q in parents if q == p) != 1:
            continue
        if any(k in ancestors(j) for k in picked):
            continue
        picked.append(int(j))
    return sorted(picked)


def _export_levels(tr: Trainer, out: Path) -> list[str]:
    """Each level's generator as ``level_N.onnx`` in ``out`` (its masked weights baked in);
    returns the file names."""
    import torch

    from pipeline.rig.networks import SkeletonConv

    files = []
    for i, G in enumerate(tr.G):
        G = G.to("cpu").eval()
        convs = [m for m in G.modules() if isinstance(m, SkeletonConv)]
        for m in convs:  # store the masked weight once, without the mask and its product
            with torch.no_grad():
                m.weight.mul_(m.mask)
            m.baked = True
        L = tr.lengths[i]
        up = torch.zeros(1, tr.F, L)
        z = torch.zeros(1, 1, L)
        name = f"level_{i + 1}.onnx"
        # The ONNX writer's OSError on a full disk names no file; torch's note on Slice
        # folding is nothing to act on.
        with warnings.catch_warnings(), naming(out / name):
            warnings.filterwarnings("ignore", message="Constant folding - Only steps=1", category=UserWarning)
            torch.onnx.export(
                G,
                (up, z),
                str(out / name),
                input_names=["up", "z"],
                output_names=["out"],
                dynamic_axes={"up": {2: "frames"}, "z": {2: "frames"}, "out": {2: "frames"}},
                opset_version=17,
                dynamo=False,
            )
        for m in convs:
            m.baked = False
        files.append(name)
    return files


def _terms(tr: Trainer) -> dict:
    """The clip's licence and credit, whether the weights may be used commercially, and what
    they learned from (the one clip): what every model folder states (models/README.md)."""
    cfg = tr.cfg
    source = {"name": f"{tr.motion.name} ({portable_path(cfg.source)})", "licence": cfg.licence,
              "frames": int(tr.lengths[-1]), "fps": float(tr.spec.fps), "use": "trained"}  # fmt: skip
    return {"licence": cfg.licence, "credit": cfg.credit, "commercial": commercial([cfg.licence]),
            "sources": [source]}  # fmt: skip


def _rig_meta(tr: Trainer, out: Path, files: list[str]) -> dict:
    """rig.json: the model's name and hash, skeleton, source clip, licence (with ``commercial``
    and ``sources``), levels, the representation the levels read and write, its training
    (metrics kept from a previous rig.json in ``out``)."""
    cfg, spec = tr.cfg, tr.spec
    sk = spec.skeleton
    names = list(sk.names)
    legs = choose_legs(sk.parents, spec.contacts)
    summary = tr.summary()
    old = {}
    if (out / "rig.json").exists():
        old = json.loads((out / "rig.json").read_text())
    return {
        "kind": "rig",
        "name": cfg.name or out.resolve().name,
        "hash": files_hash(out, files),
        "fps": float(spec.fps),
        "skeleton": {
            "names": names,
            "parents": [int(p) for p in sk.parents],
            "offsets": [[float(v) for v in o] for o in sk.offsets],
            "up_axis": sk.up_axis,
            "meters_per_unit": float(sk.meters_per_unit),
        },
        "contact_joints": [names[j] for j in spec.contacts],
        "ik_joints": [names[j] for j in legs],
        "source": {
            "path": portable_path(cfg.source),
            "clip": tr.motion.name,
            "skeleton": cfg.skeleton,
            "frames": list(cfg.frames) if cfg.frames else None,
            "train_frames": int(tr.lengths[-1]),
            "train_fps": float(spec.fps),
        },
        **_terms(tr),
        "files": {"levels": files},
        "levels": [
            {"file": f, "train_length": int(n), "noise_amplitude": float(a)}
            for f, n, a in zip(files, tr.lengths, tr.amps, strict=True)
        ],
        "representation": {
            "channels": tr.F,
            "vertices": len(tr.nb),
            "scale": float(spec.scale),
            "floor": float(spec.floor),
            "begin": [float(v) for v in tr.begin],
            "ratio": tr.sched.ratio,
            "factor": 4.0 / 3.0,
        },
        "training": summary,
        "metrics": old.get("metrics", {}),
    }


def export(tr: Trainer, out: str | Path, verify: bool = True, dest: str | Path | None = None) -> dict:
    """Write the level ONNX files, rig.json and the model card into ``out``; returns rig.json.
    ``dest``: the folder the model is moved to once complete (``out`` is then its staging
    folder), which its card names."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = _export_levels(tr, out)
    meta = _rig_meta(tr, out, files)
    if verify:
        meta["onnx_max_abs_diff"] = verify_onnx(tr, out, files)
    write_bytes(out / "rig.json", json.dumps(meta, indent=1).encode())
    write_card(out, meta, dest)
    return meta


def verify_onnx(tr: Trainer, out: Path, files: list[str], seed: int = 0) -> float:
    """Max |onnxruntime − torch| over every level, at the trained length and at another."""
    import onnxruntime as ort
    import torch

    rng = np.random.default_rng(seed)
    worst = 0.0
    for i, f in enumerate(files):
        sess = ort.InferenceSession(str(out / f), providers=["CPUExecutionProvider"])
        for L in (tr.lengths[i], max(5, tr.lengths[i] // 2 + 3)):
            up = rng.standard_normal((1, tr.F, L)).astype(np.float32) * 0.5
            z = rng.standard_normal((1, 1, L)).astype(np.float32) * 0.1
            a = sess.run(["out"], {"up": up, "z": z})[0]
            with torch.no_grad():
                b = tr.G[i].cpu()(torch.from_numpy(up), torch.from_numpy(z)).numpy()
            worst = max(worst, float(np.abs(a - b).max()))
    return worst


def _size_mb(folder: Path, files: list[str]) -> float:
    return sum((folder / f).stat().st_size for f in files) / 1e6


def _credit(meta: dict) -> str:
    """The card's credit line and what the clip's licence asks of the model's users."""
    lic = meta["licence"]
    credit = ""
    if "BY-SA" in lic:
        credit = (
            "**Licence: CC BY-SA 4.0.** The model is trained on (and so derived from) the clip "
            "above; share it and anything made from it under the same licence, with the credit "
            "above."
        )
    elif "BY-NC" in lic:
        credit = "**Licence: CC BY-NC 4.0 — non-commercial use only.**"
    if meta.get("credit"):
        credit = f"Credit: {meta['credit']}.\n\n{credit}"
    return credit


def write_card(out: str | Path, meta: dict, dest: str | Path | None = None) -> None:
    """MODEL_CARD.md from rig.json into ``out``, naming ``dest`` (default ``out``) to load."""
    out = Path(out)
    folder = Path(dest if dest is not None else out)
    t = meta["training"]
    s = meta["source"]
    sk = meta["skeleton"]
    files = meta["files"]["levels"]
    rows = "\n".join(
        f"| {', '.join(map(str, g['levels']))} | {g['iterations']} | {g['wall_s']} | "
        + ", ".join(f"{k} {v:.4g}" for k, v in g["final_losses"].items())
        + " |"
        for g in t["groups"]
    )
    lic = meta["licence"]
    credit = _credit(meta)
    metrics = meta.get("metrics") or {}
    mtext = metrics.get("markdown") or "Not measured yet (see `scripts/rig_eval_elephant.py`)."
    text = f"""# {meta["name"]}: a per-rig GANimator

A motion model of one rig learned from one clip (GANimator, Li et al. 2022; see
[docs/rig.md](../../docs/rig.md)). `RigInbetweener("{folder.as_posix()}")` fills blocked shots of
this rig and synthesizes new motion; inference is onnxruntime + numpy.

## Source

- Clip: `{s["path"]}` — `{s["clip"]}`, skeleton `{s.get("skeleton") or "(the one with most joints)"}`,
  frames {s["frames"] or "all"}, trained at {s["train_fps"]:g} fps ({s["train_frames"]} frames).
- Licence of the clip: {lic}.
- Joints ({len(sk["names"])}, as in the source, up axis {sk["up_axis"]}, metersPerUnit
  {sk["meters_per_unit"]:g}): {", ".join(sk["names"])}.
- Contact joints (labels): {", ".join(meta["contact_joints"]) or "none"}; foot IK on:
  {", ".join(meta["ik_joints"]) or "none"}.

{credit}

## Training

Schedule `{t["schedule"]["name"]}`: {t["schedule"]["iters"]} iterations per group of
{t["schedule"]["group"]} levels, {t["schedule"]["d_steps"]} discriminator steps per iteration, Adam
{t["schedule"]["lr"]:g}, coarsest level {t["schedule"]["ratio"]:.4g} × length; level lengths
{t["lengths"]}; channels {t["channels"]} in / hidden {t["hidden_channels"]}. Seed {t["seed"]},
{t["threads"]} torch thread(s) on {t["device"]}. **Wall time {t["wall_s"]:.0f} s
({t["wall_s"] / 3600:.2f} h)**.

| levels | iterations | wall s | final losses |
|---|---|---|---|
{rows}

Parameters: generators {t["generator_params"]["stored"]:,} stored
({t["generator_params"]["effective"]:,} not masked out by the skeleton),
discriminators {t["discriminator_params"]["stored"]:,} (training only). ONNX files:
{len(files)}, {_size_mb(out, files):.1f} MB; max |onnxruntime − torch| at export:
{meta.get("onnx_max_abs_diff", float("nan")):.2e}.

## Metrics

{mtext}
"""
    write_bytes(out / CARD, text.encode())
