"""Training of the global path predictor on ground-truth motion (multi-scale displacement loss, eq. 5)."""

from __future__ import annotations

import json
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from pipeline.atomic import save_torch
from pipeline.data.cache import load_split
from pipeline.data.skeletons import bandai_skeleton
from pipeline.infer.features import ROOT_SCALE, apply_transform, canonical_transform
from pipeline.motion.fk import fk
from pipeline.networks.path import PathConfig, PathPredictor
from pipeline.progress import interval
from pipeline.train.batches import sample_batch
from pipeline.train.generator_training import (
    LOG_EVERY,
    packed_clips,
    read_checkpoint,
    refuse_short,
    resumed_log,
)


def path_inputs(rot: np.ndarray, root: np.ndarray, skeleton) -> np.ndarray:
    """The path predictor's input, (B, N, J, 4), (B, N, 3) -> (B, (J−1)·3, N) root-relative
    positions, world-oriented, metres (no fill reads it: the shipped models take their root
    from the generator)."""
    _, pos = fk(rot, root, skeleton.parents, skeleton.offsets)
    rel = (pos[:, :, 1:] - pos[:, :, :1]) / ROOT_SCALE
    B, N = rel.shape[:2]
    return np.ascontiguousarray(rel.reshape(B, N, -1).transpose(0, 2, 1), np.float32)


@dataclass
class PathTrainConfig:
    steps: int = 2000
    batch: int = 32
    length: int = 128
    scales: tuple[int, ...] = (1, 2, 4, 8, 16, 32, 64)  # the paper's 1..128 needs 256-frame windows
    lr: float = 1e-3
    w_br: float = 0.01
    seed: int = 0
    threads: int = 2
    limit_clips: int | None = None
    data: str | None = None  # a folder of the studio's own takes instead of the Bandai train split
    data_include: str | None = None  # file-name globs under ``data``
    corpus: str | None = None  # a corpus description (pipeline.data.corpus) instead of either
    data_pack: str | None = None  # the train split packed by pipeline.data.pack (hosts without ../shared)
    checkpoint_minutes: float = 3.0  # the generator's --checkpoint-minutes: a run resumes from its last one
    model: PathConfig = field(default_factory=PathConfig)


def multiscale_loss(vel: torch.Tensor, root: torch.Tensor, scales) -> torch.Tensor:
    """Mean over scales n of ‖Σ predicted velocity over n frames − true displacement‖²."""
    # vel[:, :, t] is the displacement from frame t−1 to t.
    cum = torch.cumsum(vel, dim=-1)
    losses = []
    for n in scales:
        if n >= root.shape[-1]:
            continue
        pred = cum[..., n:] - cum[..., :-n]
        true = root[..., n:] - root[..., :-n]
        losses.append((pred - true).square().sum(1).mean())
    return torch.stack(losses).mean()


def _clips(cfg: PathTrainConfig):
    """What the path predictor trains on, as the generator: a packed split, a corpus, a
    studio's takes (each checked before any is read) or the train split; TweenError where no
    take is as long as its windows (else numpy's error, first batch)."""
    if cfg.data_pack:
        clips = packed_clips(cfg.data_pack)  # decoded once for the run: the generator's too
    elif cfg.corpus:
        from pipeline.train.corpus import corpus_clips

        clips = corpus_clips(cfg.corpus)
    elif cfg.data:
        from pipeline.train.corpus import studio_clips

        clips = studio_clips(cfg.data, cfg.data_include)
    else:
        clips = load_split("train", limit=cfg.limit_clips)
    refuse_short(cfg, clips, cfg.length, "the path predictor's windows",
                 "give longer takes, or --path-steps 0 to train the generator only")  # fmt: skip
    return clips


def train_path(cfg: PathTrainConfig, out_dir: Path) -> Path:
    from pipeline.networks.layers import batch_regularisation

    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    skel = bandai_skeleton()
    clips = _clips(cfg)
    out_dir.mkdir(parents=True, exist_ok=True)  # the data read first: a refusal writes nothing
    model = PathPredictor(cfg.model)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.steps)
    ckpt = out_dir / "path.pt"
    step = 0
    if ckpt.exists():
        state = read_checkpoint(
            ckpt, "the run's path checkpoint", hint="; remove it to train the path predictor again"
        )
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["opt"])
        sched.load_state_dict(state["sched"])
        step = state["step"]
    log = resumed_log(out_dir / "path_log.jsonl", step)
    t0 = t_ckpt = time.time()

    def save() -> None:  # whole or not at all: a run killed while saving resumes from the last one
        state = {"model": model.state_dict(), "opt": opt.state_dict(), "sched": sched.state_dict(),
                 "step": step, "config": asdict(cfg)}  # fmt: skip
        save_torch(state, ckpt)

    bar = tqdm(total=cfg.steps, initial=step, file=sys.stderr, desc="path predictor", mininterval=interval())
    while step < cfg.steps:
        rng = np.random.default_rng([cfg.seed, 7, step])
        rot, root = sample_batch(clips, rng, cfg.batch, cfg.length)
        q, off = canonical_transform(rot[:, 0], root[:, 0], skel)
        rot, root = apply_transform(rot, root, q, off)
        x = torch.from_numpy(path_inputs(rot, root, skel))
        target = torch.from_numpy(np.ascontiguousarray((root / ROOT_SCALE).transpose(0, 2, 1), np.float32))
        vel = model(x)
        loss = multiscale_loss(vel, target, cfg.scales) + cfg.w_br * batch_regularisation(model.res_layers())
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        sched.step()
        step += 1
        bar.update(1)
        if step % LOG_EVERY == 0:
            log.write(json.dumps({"step": step, "loss": loss.item(), "t": time.time() - t0}) + "\n")
            log.flush()
            bar.set_postfix(loss=f"{loss.item():.5f}")
        if time.time() - t_ckpt > cfg.checkpoint_minutes * 60:
            save()
            t_ckpt = time.time()
    save()
    bar.close()
    return ckpt
