"""Filling a shot: the API the farm (``workers/``) and ``tween fill-local`` call.

``validate_shot`` checks everything before any work; ``fill_take`` computes one take into
an ``.npz`` (idempotent: same inputs → same file); ``write_layers`` writes the versioned
fill layer and the review root layer; ``fill_shot`` does all three in process.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from pipeline.errors import ShotError, TweenError


@dataclass
class FillOptions:
    """JSON-serialisable (``asdict``): it travels in Celery messages."""

    keys: str | None = None  # "1001,1012,1030" or "1001-1100x8"; None = authored samples / tween:keyTimes
    range: str | None = None  # "1010-1050"; None = whole key span
    takes: int = 1
    seed: int = 0
    model: str = "default"  # passed to pipeline.infer.load_inbetweener
    out_dir: str | None = None  # default: beside the shot
    fmt: str = "usda"  # or "usdc"
    mapping: str | None = None  # JSON joint-mapping override file
    review_layer: str | None = None  # root layer to add the fill to instead of a new review layer


_MODELS: dict[tuple[int, str], object] = {}


def _model(name: str):
    """The in-betweener ``name``, loaded once per process (a forked worker loads its own:
    onnxruntime sessions must not cross a fork)."""
    from pipeline.infer.api import load_inbetweener

    key = (os.getpid(), name)
    if key not in _MODELS:
        try:
            _MODELS[key] = load_inbetweener(name)
        except FileNotFoundError as e:
            raise TweenError(f"model {name!r}: {e}") from None
    return _MODELS[key]


def _plan(shot: str, opts: FillOptions, fps: float):
    from pipeline.usd.plan import make_plan

    if opts.takes < 1:
        raise TweenError(f"takes must be at least 1, not {opts.takes}")
    if opts.fmt not in ("usda", "usdc"):
        raise TweenError(f"format must be usda or usdc, not {opts.fmt!r}")
    return make_plan(str(shot), opts.keys, opts.range, opts.mapping, fps)


def validate_shot(shot: str, opts: FillOptions) -> dict:
    """Raises ShotError on bad input; returns a JSON-safe summary of what will be filled."""
    from pipeline.usd.write import check_out_dir

    inb = _model(opts.model)
    summary = _plan(shot, opts, float(inb.fps)).summary()
    summary["out_dir"] = str(check_out_dir(shot, opts.out_dir))
    summary.update(model=inb.name, model_hash=inb.model_hash)
    return summary


def _digest(shot: str, stage, opts: FillOptions, take: int, model_hash: str) -> str:
    """Hash of every layer file the shot uses, the options that change values, the take, the model."""
    h = hashlib.sha256()
    for path in sorted({layer.realPath for layer in stage.GetUsedLayers() if layer.realPath}):
        h.update(path.encode())
        h.update(Path(path).read_bytes())
    if opts.mapping:
        h.update(Path(opts.mapping).read_bytes())
    d = {k: v for k, v in asdict(opts).items() if k in ("keys", "range", "seed", "model", "mapping")}
    h.update(json.dumps([os.path.realpath(shot), d, take, model_hash], sort_keys=True).encode())
    return h.hexdigest()[:16]


def fill_take(shot: str, opts: FillOptions, take: int, work_dir: str) -> str:
    """Fills every character for take ``take`` (seed = opts.seed + take) into an .npz."""
    from pipeline.usd.solve import fill_character

    inb = _model(opts.model)
    plan = _plan(shot, opts, float(inb.fps))
    try:
        digest = _digest(shot, plan.shot.stage, opts, take, inb.model_hash)
    except OSError as e:
        raise ShotError(shot, f"cannot read: {e.strerror}") from None
    out = Path(work_dir) / f"{Path(shot).name.split('.')[0]}.take{take:03d}.{digest}.npz"
    if out.exists():
        return str(out)
    arrays: dict[str, np.ndarray] = {}
    chars = []
    for i, cp in enumerate(plan.chars):
        data = fill_character(plan, cp, inb, seed=opts.seed + take)
        for k, v in data.items():
            arrays[f"c{i}_{k}"] = v
        c = cp.char
        chars.append({"anim": c.anim_path, "skel": c.skel_path, "joints": list(c.anim_joints),
                      "keys": [float(x) for x in cp.keys]})  # fmt: skip
    meta = {"shot": os.path.realpath(shot), "take": take, "seed": opts.seed + take, "model": inb.name,
            "model_hash": inb.model_hash, "chars": chars}  # fmt: skip
    arrays["meta"] = np.array(json.dumps(meta))
    Path(work_dir).mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=work_dir, prefix=f".{out.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return str(out)


def load_take(path: str) -> dict:
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
        data = [
            {k: z[f"c{i}_{k}"] for k in ("times", "rot", "trans", "scale", "keys")}
            for i in range(len(meta["chars"]))
        ]
    return dict(meta, data=data)


def write_layers(shot: str, opts: FillOptions, take_files: list[str], job_id: str = "") -> dict:
    """Writes the versioned fill layer (+ tweenTake variants when takes > 1) and the review
    root layer; returns {"layer", "review", "version", "takes", "model", "model_hash"}.
    Idempotent per ``job_id``."""
    from pipeline.usd import write
    from pipeline.usd.read import open_stage

    out_dir = Path(opts.out_dir) if opts.out_dir else Path(shot).resolve().parent
    if job_id and out_dir.is_dir():
        done = write.find_job(out_dir, write.shot_stem(shot), job_id)
        if done:
            return done
    if not take_files:
        raise ShotError(shot, "no takes to write")
    takes = sorted((load_take(p) for p in take_files), key=lambda t: t["take"])
    for t in takes:
        if t["shot"] != os.path.realpath(shot):
            raise ShotError(shot, f"take file {t['shot']} was filled from another shot")
        if [c["anim"] for c in t["chars"]] != [c["anim"] for c in takes[0]["chars"]]:
            raise ShotError(shot, "take files disagree on the shot's characters")
    stage = open_stage(shot)
    meta = {"model": takes[0]["model"], "model_hash": takes[0]["model_hash"], "job_id": job_id}
    return write.write(shot, stage, takes, meta, opts.out_dir, opts.fmt, opts.review_layer)


def fill_shot(shot: str, opts: FillOptions, job_id: str = "") -> dict:
    """Validate, fill every take and write, in this process."""
    summary = validate_shot(shot, opts)
    with tempfile.TemporaryDirectory(prefix="tween-") as work:
        files = [fill_take(shot, opts, t, work) for t in range(opts.takes)]
        result = write_layers(shot, opts, files, job_id)
    result["characters"] = summary["characters"]
    return result
