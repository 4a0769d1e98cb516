"""Training loop of the local motion generator (supervised reconstruction on in-between frames).

Losses on the frames between keys: L1 on rotation matrices, L1 on FK joint positions, their
frame-to-frame velocities and the root (in decimetres), foot-contact BCE, and the batch-regularisation term of eq. 9.
Checkpoints every few minutes; resumes from the last one; deterministic for a seed.
"""

from __future__ import annotations

import json
import os
import pickle
import sys
import time
from dataclasses import asdict, dataclass, field, fields, replace
from functools import partial
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from pipeline.atomic import save_torch, write_bytes
from pipeline.data.cache import ClipSet, load_split
from pipeline.data.skeletons import FOOT_JOINTS, bandai_mirror, bandai_skeleton
from pipeline.errors import TweenError
from pipeline.infer.dna_poses import POSE_SCALE, dna_poses, representative_frames
from pipeline.infer.features import (
    NOISE_CHANNELS,
    ROOT_SCALE,
    build_features,
    feature_options,
    key_neighbours,
)
from pipeline.inputs import not_a_file, refused_for_safety
from pipeline.motion.augment import joint_offsets
from pipeline.motion.fk import fk
from pipeline.networks.discriminator import Discriminator, DiscriminatorConfig, d_loss, g_loss
from pipeline.networks.generator import Generator, GeneratorConfig
from pipeline.networks.layers import batch_regularisation
from pipeline.progress import interval
from pipeline.train.batches import (
    PARTIAL_LAYOUTS,
    foot_contacts,
    insert_partial_keys,
    sample_batch,
    sample_joint_keys,
    sample_keys,
)
from pipeline.train.keymatch import match_partial_keys, partial_match_weights

OFFSET_SHARE = 0.5  # windows given --joint-offsets: the other half keeps the capture's own poses
POS_SCALE = 10.0  # position losses in decimetres: centimetre errors must weigh against rotations
LOG_EVERY = 25  # steps between the lines of a run's log (train_log.jsonl, path_log.jsonl)


def _knob(default, help: str, **meta):
    """A TrainConfig field: its default and its `tween train --help` text, declared once here."""
    return field(default=default, metadata={"help": help, **meta})


@dataclass
class TrainConfig:
    """Every knob of a generator training run. `tween train` makes one flag of each field
    (``--gap-start`` for ``gap_start``; pipeline/train/recipe.py), with this default and help.
    ``model`` is the network's config; the fields of it that `tween train` sets are listed in
    its ``flags`` metadata (flag name: (GeneratorConfig field, help))."""

    steps: int = _knob(8000, "Generator steps.")
    batch: int = _knob(32, "Windows per batch (path predictor and generator).")
    lengths: tuple[int, ...] = _knob((64, 96, 128), "Training window lengths, comma-separated.")
    lr: float = _knob(1e-3, "Peak learning rate of the one-cycle schedule.")
    gap_start: int = _knob(15, "Longest gap (frames) at the start of the gap curriculum.")
    gap_end: int = _knob(90, "Longest gap (frames) once the curriculum is through: the longest trained gap.")
    curriculum: float = _knob(
        0.4, "Share of the steps over which the longest gap grows from --gap-start to --gap-end."
    )
    w_rot: float = _knob(1.0, "Weight of the L1 loss on rotation matrices.")
    w_pos: float = _knob(1.0, "Weight of the L1 loss on FK joint positions (decimetres).")
    w_root: float = _knob(1.0, "Weight of the L1 loss on the root (decimetres).")
    w_vel: float = _knob(
        1.0, "Weight of the joint-velocity L1 loss: suppresses frame-to-frame jitter (foot skate, L2P)."
    )
    w_contact: float = _knob(0.1, "Weight of the foot-contact BCE loss.")
    w_br: float = _knob(0.01, "Weight of the batch-regularisation loss (eq. 9), generator and discriminator.")
    noise_prob: float = _knob(0.5, "Share of batches with a random take latent (else the zero latent).")
    adv_start: int | None = _knob(
        6800,
        "Generator step where the LSGAN refinement starts (none: -1).",
        none_if_negative=True,
    )
    w_adv: float = _knob(0.02, "Weight of the LSGAN term in the refinement.")
    d_lr: float = _knob(1e-4, "Learning rate of the discriminator.")
    seed: int = _knob(0, "Seed of weights and batches: a run is deterministic for a seed.")
    threads: int = _knob(1, "torch threads; 1 is fastest on 2 shared cores (more threads thrash).")
    checkpoint_minutes: float = _knob(3.0, "Minutes between checkpoints (a run resumes from its last one).")
    limit_clips: int | None = _knob(
        None, "Use only the first N clips of the train split or of --data (smoke tests)."
    )
    data: str | None = _knob(
        None,
        "A folder of your own takes instead of Bandai train: BVH or USD of any humanoid rig, "
        "mapped and retargeted onto the model skeleton as a fill does.",
        path=True,
    )
    data_include: str | None = _knob(
        None, "With --data: only the takes whose file names match these comma-separated globs."
    )
    corpus: str | None = _knob(
        None,
        "A corpus description (TOML/JSON: sources of any rig, each with its licence and weight; "
        "pipeline/data/corpus.py) instead of Bandai train: prepared once (resumable), windows "
        "drawn by source weight.",
        path=True,
    )
    init: str | None = _knob(
        None,
        "Continue from these weights: a generator checkpoint, or a model folder (its "
        "torch/generator.pt; e.g. models/default). The network's shape comes from it.",
        path=True,
    )
    pos_zscore: bool = _knob(False, "Weigh position errors by 1/std per coordinate (train statistics).")
    data_pack: str | None = _knob(
        None, "Train split packed by `python -m pipeline.data.pack` (hosts without ../shared).", path=True
    )
    gap_weighting: float = _knob(
        0.0, "Weigh frames by gap length ** -this (0: every frame alike; 1: every gap alike)."
    )
    mirror: float = _knob(0.0, "Share of windows mirrored left/right (augmentation).")
    joint_offsets: float = _knob(
        0.0,
        "Degrees (RMS angle) of a constant random rotation on each joint but the root, one per "
        "window and joint, on half the windows, keys and targets alike: another actor's or "
        "rig's posture (augmentation; 0: none).",
    )
    partial: float = _knob(0.0, "Share of batches with partial keys (some joints only; needs --key-adapter).")
    partial_layout: str = _knob(
        "convert",
        "Partial keys in training: 'convert' some keys, or 'insert' them in gaps.",
        choices=PARTIAL_LAYOUTS,
    )
    dna_prob: float = _knob(0.5, "Share of windows given a motion DNA (with --dna).")
    dna_max: int = _knob(4, "Poses per motion DNA: 1 ... this.")
    w_dna: float = _knob(
        0.5, "Weight of the DNA loss (eq. 11): every DNA pose should appear among the in-betweens."
    )
    dna_from: float = _knob(0.0, "Share of DNAs from the rest of the window's clip (else from its gap).")
    new_lr: float = _knob(10.0, "Learning-rate factor of the weights the --init checkpoint lacks.")
    freeze: bool = _knob(False, "Train only the add-on modules (DNA, adapter); the trunk stays as it was.")
    device: str = _knob("cpu", "cpu, or cuda where a GPU is available (batches are still made on CPU).")
    workers: int = _knob(
        0, "Processes making batches ahead (0: in the training process; useful with --device cuda)."
    )
    model: GeneratorConfig = field(
        default_factory=GeneratorConfig,
        metadata={
            "flags": {
                "key_adapter": (
                    "key_adapter",
                    "Partial keys as a side input through a zero-start adapter; the main input is that "
                    "of the full keys alone (with --freeze, fills from full keys stay bit for bit).",
                ),
                "delta": (
                    "delta",
                    "Pose inputs relative to the keys (the Δ-interpolator's delta mode): the "
                    "baseline as its change since the first key, the key copy as its offset from it.",
                ),
                "dna": (
                    "dna",
                    "Motion-DNA encoder width (0: none); new to an --init checkpoint, it starts at zero.",
                ),
            }
        },
    )

    def __post_init__(self):
        if self.partial_layout not in PARTIAL_LAYOUTS:
            raise ValueError(f"partial_layout {self.partial_layout!r}: expected one of {PARTIAL_LAYOUTS}")
        for name, (lo, hi) in _RANGES.items():
            v = getattr(self, name)
            values = v if isinstance(v, tuple) else (v,)
            if v is None and name in ("limit_clips", "adv_start"):
                continue
            if not values or not all(isinstance(x, int | float) and lo <= x <= hi for x in values):
                flag = "--" + name.replace("_", "-")
                raise ValueError(f"{flag} {v!r}: must be from {lo:g} to {hi:g}")
        given = [f for f, v in (("--data", self.data), ("--data-pack", self.data_pack),
                                ("--limit-clips", self.limit_clips), ("--pos-zscore", self.pos_zscore)) if v]  # fmt: skip
        if self.corpus and given:
            raise ValueError(f"--corpus {self.corpus}: reads its own sources; drop {', '.join(given)}")
        if self.data_pack and self.data:  # the pack was trained on and --data passed over, unsaid
            raise ValueError(
                f"--data-pack {self.data_pack}: holds the clips to train on; drop --data {self.data}"
            )
        if self.data_pack and self.limit_clips:  # a pack is read whole (its clips are one array)
            raise ValueError(
                f"--data-pack {self.data_pack}: trains on every clip it holds; drop --limit-clips"
            )
        if self.gap_end < self.gap_start:
            raise ValueError(f"--gap-end {self.gap_end}: must be at least --gap-start {self.gap_start}")


_SHARE, _WEIGHT = (0.0, 1.0), (0.0, 1e6)
#: Each numeric knob's accepted range (a NaN fails every one). The one-cycle schedule needs
#: 4 steps; windows shorter than 16 frames hold no gap worth training.
_RANGES = {
    "steps": (4, 1e9), "batch": (1, 1e5), "lengths": (16, 10_000), "lr": (1e-12, 10.0),
    "gap_start": (1, 10_000), "gap_end": (1, 10_000), "curriculum": _SHARE,
    "w_rot": _WEIGHT, "w_pos": _WEIGHT, "w_root": _WEIGHT, "w_vel": _WEIGHT, "w_contact": _WEIGHT,
    "w_br": _WEIGHT, "w_adv": _WEIGHT, "w_dna": _WEIGHT, "noise_prob": _SHARE, "adv_start": (0, 1e9),
    "d_lr": (1e-12, 10.0), "seed": (0, 2**31 - 1), "threads": (1, 256), "checkpoint_minutes": (1e-3, 1e6),
    "limit_clips": (1, 1e9), "gap_weighting": (0.0, 10.0), "mirror": _SHARE, "partial": _SHARE,
    "joint_offsets": (0.0, 90.0),
    "dna_prob": _SHARE, "dna_max": (1, 1000), "dna_from": _SHARE, "new_lr": (1e-6, 1e6), "workers": (0, 256),
}  # fmt: skip


def sixd_to_matrix_t(d6: torch.Tensor) -> torch.Tensor:
    a1, a2 = d6[..., :3], d6[..., 3:]
    b1 = torch.nn.functional.normalize(a1, dim=-1)
    b2 = torch.nn.functional.normalize(a2 - (b1 * a2).sum(-1, keepdim=True) * b1, dim=-1)
    return torch.stack([b1, b2, torch.cross(b1, b2, dim=-1)], dim=-1)


def decode(out: torch.Tensor, feats: torch.Tensor, n_joints: int):
    """Network output + baseline channels -> (rotation matrices, root (cm), contact logits)."""
    B, _, N = out.shape
    J6 = n_joints * 6
    o = out.transpose(1, 2)
    base = feats.transpose(1, 2)[..., : J6 + 3]
    mats = sixd_to_matrix_t((base[..., :J6] + o[..., :J6]).reshape(B, N, n_joints, 6))
    root = (base[..., J6:] + o[..., J6 : J6 + 3]) * ROOT_SCALE
    return mats, root, o[..., J6 + 3 : J6 + 7]


def init_checkpoint(init: str) -> Path:
    """``--init`` as a checkpoint file: a model folder gives its ``torch/generator.pt``, a run
    folder its ``generator.pt``."""
    p = Path(init)
    if p.is_dir():
        for c in (p / "torch" / "generator.pt", p / "generator.pt"):
            if c.is_file():
                return c
        raise TweenError(f"{p}: --init folder holds no torch/generator.pt or generator.pt")
    if (why := not_a_file(p, "checkpoint")) == "file not found":
        raise TweenError(f"{p}: --init checkpoint not found")
    if why is not None:  # a pipe said "not found" (it is there, and would block a read)
        raise TweenError(f"{p}: --init: {why}")
    return p


def read_checkpoint(path: Path, role: str, map_location="cpu", hint: str = "", config: bool = True) -> dict:
    """A checkpoint that ``tween train`` wrote, refused in one line naming the file and its
    ``role`` (``--init``, the run's own) when it is not one: an ONNX export, a truncated or
    foreign file."""
    what = "an ONNX export" if path.suffix == ".onnx" else "not a checkpoint that `tween train` wrote"
    if os.path.exists(path) and (odd := not_a_file(path, "checkpoint")) is not None:
        raise TweenError(f"{path}: {role}: {odd}{hint}")  # a pipe would block torch.load for ever
    try:  # weights_only: a checkpoint holds tensors and plain values; a crafted one runs no code
        state = torch.load(path, weights_only=True, map_location=map_location)
    except pickle.UnpicklingError as e:
        if refused_for_safety(path, e):  # weights_only refused what it names (os.system, a class)
            raise TweenError(
                f"{path}: {role}: holds something other than tensors and plain values and was "
                f"refused for safety (nothing in it was run){hint}"
            ) from None
        raise TweenError(f"{path}: {role}: {what} ({type(e).__name__}){hint}") from None
    except Exception as e:  # torch raises pickle, zip, EOF and runtime errors alike
        raise TweenError(f"{path}: {role}: {what} ({type(e).__name__}){hint}") from None
    if (
        not isinstance(state, dict)
        or not isinstance(state.get("model"), dict)
        or (config and "config" not in state)
    ):
        raise TweenError(f"{path}: {role}: a torch file without a network's weights and config{hint}")
    return state


def load_init(init: str, map_location="cpu") -> dict:
    """The ``--init`` checkpoint's state (``init_checkpoint``, ``read_checkpoint``)."""
    hint = "; give a run folder's generator.pt or a model folder with torch/generator.pt"
    path = init_checkpoint(init)
    state = read_checkpoint(path, "--init", map_location, hint, config=False)  # weights suffice
    if not isinstance(state.get("config", {}), dict):
        raise TweenError(f"{path}: --init: its config is {type(state['config']).__name__}, not a table{hint}")
    return state


# Add-on modules a run may give a network it continues (each starts from zero beside the
# trained weights); every other field of the network's shape is the checkpoint's.
ADDONS = ("key_adapter", "dna", "delta")


def to_delta_inputs(weights: dict, n_joints: int) -> dict:
    """An absolute-input checkpoint's weights for the same network in delta mode
    (``GeneratorConfig.delta``): the input convolution reads the baseline B and the key copy
    K as W_b·B + W_k·K; delta mode gives it B − B₀ and K − B, so with W_b' = W_b + W_k and
    W_k' = W_k it computes the same up to the constant −(W_b + W_k)·B₀ (the first key's
    pose, which is what delta mode withholds) and the window edges' padding. A continuation
    thus starts next to the network it continues instead of from scratch."""
    c = n_joints * 6 + 3
    w = weights["inp.conv.weight"].clone()  # (width, C_in, k)
    w[:, :c] = w[:, :c] + w[:, c : 2 * c]
    return {**weights, "inp.conv.weight": w}


def inherit_model(given: GeneratorConfig, saved: dict | None) -> GeneratorConfig:
    """The network a run continuing a checkpoint trains: the checkpoint's (``saved``, its
    config's "model"), with the add-ons the run's flags ask for switched on as well."""
    if not saved:
        return given
    kept = GeneratorConfig.saved(saved)
    return replace(kept, **{k: max(getattr(kept, k), getattr(given, k)) for k in ADDONS})


def make_discriminator(cfg: TrainConfig, dev=None):
    disc = Discriminator(DiscriminatorConfig(n_joints=cfg.model.n_joints)).to(dev or "cpu")
    return disc, torch.optim.Adam(disc.parameters(), lr=cfg.d_lr, betas=(0.5, 0.99))


def rel_positions(pos: torch.Tensor) -> torch.Tensor:
    """(B, N, J, 3) cm -> (B, (J−1)·3, N) root-relative metres, the discriminator's input."""
    rel = (pos[:, :, 1:] - pos[:, :, :1]) / ROOT_SCALE
    return rel.flatten(2).transpose(1, 2)


def step_batch(cfg: TrainConfig, clips, skel, feet: list[int], step: int) -> dict | None:
    """Everything step ``step`` trains on, made in numpy from (seed, step) alone, so that
    resuming replays the same batches and batch-making processes agree with each other."""
    # Long because it runs in the order its random draws are taken: every run, resumed or
    # replayed, depends on that order bit for bit, which a split would make easy to change unseen.
    rng = np.random.default_rng([cfg.seed, step])
    frac = min(step / max(cfg.curriculum * cfg.steps, 1), 1.0)
    max_gap = int(cfg.gap_start + frac * (cfg.gap_end - cfg.gap_start))
    L = int(rng.choice(cfg.lengths))
    where: list = []
    rot, root = sample_batch(clips, rng, cfg.batch, L, where)
    if cfg.mirror > 0:
        # Its own stream, so a mirrored run trains on the same windows and keys as a plain one.
        flip = np.random.default_rng([cfg.seed, step, 1]).random(cfg.batch) < cfg.mirror
        m = bandai_mirror()
        rot[flip] = m.rotations(rot[flip], skel.parents).astype(rot.dtype)
        root[flip] = m.root(root[flip]).astype(root.dtype)
    if cfg.joint_offsets > 0:
        # Its own stream too: the windows and keys stay those of a run without offsets.
        orng = np.random.default_rng([cfg.seed, step, 5])
        rot = joint_offsets(rot, orng, cfg.joint_offsets, OFFSET_SHARE)
    keys = sample_keys(rng, L, max_gap)
    adversarial = cfg.adv_start is not None and step >= cfg.adv_start
    noise = None
    if adversarial or rng.random() < cfg.noise_prob:
        noise = rng.normal(size=(cfg.batch, NOISE_CHANNELS))
    joint_keys = None
    if cfg.partial > 0:
        # Its own stream, so that the windows and keys stay those of a run without partial keys.
        prng = np.random.default_rng([cfg.seed, step, 3])
        if prng.random() < cfg.partial:
            if cfg.partial_layout == "insert":
                keys, joint_keys = insert_partial_keys(prng, keys, len(skel))
            else:
                joint_keys = sample_joint_keys(prng, len(keys), len(skel))
    feats, ctx = build_features(
        rot, root, keys, skel, noise, joint_keys=joint_keys, **feature_options(asdict(cfg.model))
    )
    _, gpos = fk(ctx["crot"], ctx["croot"], skel.parents, skel.offsets)
    between = np.zeros(L, bool)
    between[keys[0] : keys[-1] + 1] = True
    # Frames of full keys are given; a partial key's other joints are still to predict.
    full = keys if joint_keys is None else keys[joint_keys.all(axis=1)]
    between[full] = False
    if not between.any():
        return None
    # Long gaps hold most frames and the largest errors; weighting by gap length ** −α stops
    # them from drowning the short transitions, where only a small correction is needed.
    prev, nxt = key_neighbours(L, keys)
    fw = np.maximum(nxt - prev, 1).astype(np.float64) ** -cfg.gap_weighting
    fw = fw / fw[between].mean()
    t = torch.from_numpy
    extra = {}
    if cfg.model.dna:
        extra = {k: t(v) for k, v in sample_dna(cfg, ctx, between, skel, step, clips, where).items()}
    if joint_keys is not None:  # the losses see partial keys matched, as the farm matches them
        extra["match_w"] = t(partial_match_weights(L, keys, joint_keys))
        extra["all_keys"] = t(keys)
    return {
        **extra,
        "feats": t(feats),
        "crot": t(ctx["crot"].astype(np.float32)),
        "croot": t(ctx["croot"].astype(np.float32)),
        "gpos": t(gpos.astype(np.float32)),
        "contacts": t(foot_contacts(gpos, feet)),
        "between": t(between),
        "frame_weight": t(fw.astype(np.float32)),
        "keys": t(full),
        "max_gap": max_gap,
        "L": L,
    }


def sample_dna(cfg: TrainConfig, ctx: dict, between: np.ndarray, skel, step: int, clips, where) -> dict:
    """A DNA per window: 1 … ``dna_max`` representative poses, on a ``dna_prob`` share of
    windows. They come from the window's own in-between frames (picked among a random half of
    them, so the choice varies) or, on a ``dna_from`` share, from the rest of its clip, at
    least 15 frames from the window: the same motion, poses the keys alone do not give away."""
    rng = np.random.default_rng([cfg.seed, step, 4])
    inner = np.flatnonzero(between)
    L = len(between)
    R = int(rng.integers(1, cfg.dna_max + 1))
    poses = []
    for b in range(len(ctx["crot"])):
        c, off = where[b]
        rot, _ = clips.clip(c)
        rest = np.r_[np.arange(0, max(off - 15, 0)), np.arange(off + L + 15, len(rot))]
        if rng.random() < cfg.dna_from and len(rest) >= R:
            idx = np.resize(representative_frames(rot, R, spacing=5, frames=rest), R)
            poses.append(dna_poses(rot[idx], np.zeros((R, 3)), skel))
            continue
        some = np.sort(rng.choice(inner, size=max(1, len(inner) // 2), replace=False))
        idx = representative_frames(ctx["crot"][b], R, spacing=5, frames=some)
        idx = np.resize(idx, R)  # fewer far-enough frames than R: repeat
        poses.append(dna_poses(ctx["crot"][b, idx], ctx["croot"][b, idx], skel))
    on = (rng.random((len(poses), 1)) < cfg.dna_prob).astype(np.float32)
    return {"dna": np.stack(poses), "dna_weight": on}


def facing_poses(pos: torch.Tensor, skel) -> torch.Tensor:
    """(B, L, J, 3) -> (B, L, J − 1, 3) root-relative positions turned to face +X, in metres
    (the torch twin of ``pipeline.infer.dna_poses.dna_poses``)."""
    across = pos[..., skel.index("UpperLeg_L"), :] - pos[..., skel.index("UpperLeg_R"), :]
    fx, fz = -across[..., 2:3], across[..., 0:1]  # across × up, (B, L, 1)
    norm = torch.sqrt(fx**2 + fz**2).clamp_min(1e-6)
    c, s = fx / norm, fz / norm
    rel = pos[..., 1:, :] - pos[..., :1, :]
    x, y, z = rel[..., 0], rel[..., 1], rel[..., 2]
    return torch.stack([c * x + s * z, y, c * z - s * x], -1) / POSE_SCALE


def dna_loss(
    ppos: torch.Tensor, dna: torch.Tensor, on: torch.Tensor, between: torch.Tensor, skel
) -> torch.Tensor:
    """Eq. 11: each DNA pose's distance (mean per joint, decimetres) to its nearest in-between
    frame, averaged over the poses of the windows that have a DNA."""
    if not bool(on.any()):
        return torch.zeros((), device=ppos.device)
    B, C, R = dna.shape
    pred = facing_poses(ppos[:, between], skel)  # (B, T, J − 1, 3)
    want = dna.reshape(B, -1, 3, R).permute(0, 3, 1, 2)  # (B, R, J − 1, 3)
    d = torch.linalg.norm(pred[:, None] - want[:, :, None], dim=-1).mean(-1) * 10.0  # (B, R, T)
    nearest = d.min(dim=2).values.mean(dim=1)
    w = on[:, 0]
    return (nearest * w).sum() / w.sum()


class _Steps(torch.utils.data.Dataset):
    def __init__(self, make, first: int, last: int):
        self.make, self.first, self.last = make, first, last

    def __len__(self) -> int:
        return self.last - self.first

    def __getitem__(self, i: int):
        return self.make(self.first + i)


def _one_thread(_):
    torch.set_num_threads(1)


def batches_from(cfg: TrainConfig, clips, skel, feet, first: int):
    """Iterator over the batches of steps ``first`` … ``cfg.steps − 1``, made ahead by
    ``cfg.workers`` processes when asked (a GPU step is faster than one batch in numpy)."""
    make = partial(step_batch, cfg, clips, skel, feet)
    if cfg.workers <= 0:
        return (make(s) for s in range(first, cfg.steps))
    loader = torch.utils.data.DataLoader(
        _Steps(make, first, cfg.steps),
        batch_size=None,
        num_workers=cfg.workers,
        prefetch_factor=4,
        worker_init_fn=_one_thread,
        collate_fn=lambda b: b,
    )
    return iter(loader)


#: The pack decoded last in this process, by (its real path, device, inode, size, mtime) and
#: (that key, its ClipSet): a run's up-front check, its path predictor and its generator decode
#: it once between them (seconds each); one pack at a time is kept.
_PACKED: list = []


def packed_clips(path: str) -> ClipSet:
    """The ``--data-pack`` at ``path`` decoded (once while it stays unchanged: ``_PACKED``);
    TweenError naming it where it is no pack or holds another skeleton's clips."""
    from pipeline.data.pack import load_pack

    try:
        st = os.stat(path)
        key = (os.path.realpath(path), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
    except (OSError, ValueError):
        key = None  # load_pack names what it is instead
    if key is not None and _PACKED and _PACKED[0] == key:
        return _PACKED[1]
    _PACKED.clear()  # the last pack let go before another is decoded
    clips = load_pack(path, "--data-pack")
    joints = len(bandai_skeleton())
    if clips.rotations.shape[1] != joints:  # another skeleton's clips: a shape error in training
        raise TweenError(
            f"{path}: --data-pack: its clips have {clips.rotations.shape[1]} joints, the model skeleton {joints}"
        )
    if key is not None:
        _PACKED[:] = [key, clips]
    return clips


def training_clips(cfg: TrainConfig):
    """What a run trains on: a packed split, a studio's takes (``--data``, each checked before
    any is read) or the train split; TweenError where no take is long enough for ``--lengths``."""
    if cfg.data_pack:
        clips = packed_clips(cfg.data_pack)
    elif cfg.corpus:
        from pipeline.train.corpus import corpus_clips

        clips = corpus_clips(cfg.corpus)
    elif cfg.data:
        from pipeline.train.corpus import studio_clips

        clips = studio_clips(cfg.data, cfg.data_include, cfg.limit_clips)
    else:
        clips = load_split("train", limit=cfg.limit_clips)
    n = max(cfg.lengths)
    refuse_short(cfg, clips, n, f"--lengths {n}", "give longer takes or shorter --lengths")
    if cfg.corpus and clips.groups is not None:
        _check_source_lengths(cfg, clips)
    return clips


def refuse_short(cfg, clips, n: int, what: str, remedy: str) -> None:
    """TweenError where no take of the run's data (``cfg``: a corpus, a studio's takes or the
    train split) is ``n`` frames long, the length ``what`` needs (numpy's error at the first
    batch otherwise), naming the longest and ``remedy``."""
    if not (clips.lengths >= n).any():
        where = cfg.corpus or cfg.data or getattr(cfg, "data_pack", None) or "the train split"
        raise TweenError(
            f"{where}: no take of {n} frames (at 30 fps) for {what}; the longest is {int(clips.lengths.max())}: {remedy}"
        )


def _check_source_lengths(cfg: TrainConfig, clips) -> None:
    """TweenError naming a corpus source with no take as long as the longest ``--lengths``:
    its windows of that length could not be drawn, and its weight would go to the others
    (ClipSet.draw_p) with nothing said."""
    n = max(cfg.lengths)
    groups = np.asarray(clips.groups)
    for g in np.unique(groups):
        at = np.flatnonzero(groups == g)
        longest = int(clips.lengths[at].max())
        if longest < n:
            source = clips.names[at[0]].split("/", 1)[0]
            raise TweenError(
                f"{cfg.corpus}: source {source}: no take of {n} frames (at 30 fps) for --lengths {n}; "
                f"its longest is {longest}: its share would go to the other sources. Give it longer "
                "takes, drop it, or give shorter --lengths"
            )


def check_partial(cfg: TrainConfig, saved: dict | None = None) -> None:
    """TweenError unless a ``--partial`` run trains a key adapter (``--key-adapter``, or the
    ``--init`` network's: ``saved`` is its config's "model"). Without one the fill never gives
    the network partial keys (it fills from the full ones and matches the rest afterwards:
    OnnxInbetweener._solve), so training on them would teach it inputs it never sees."""
    if cfg.partial > 0 and not (cfg.model.key_adapter or (saved or {}).get("key_adapter")):
        raise TweenError(
            f"--partial {cfg.partial:g}: partial keys train the key adapter; give --key-adapter "
            "(or an --init network that has one)"
        )


def _with_init(cfg: TrainConfig, dev) -> tuple[TrainConfig, dict | None]:
    """The run's config with the network of its ``--init`` checkpoint (inherit_model), and
    that checkpoint's weights (turned to delta inputs where the run adds them), or None.
    TweenError where ``--partial`` has no key adapter to train (:func:`check_partial`)."""
    if not cfg.init:
        check_partial(cfg)
        return cfg, None
    state = load_init(cfg.init, dev)
    init = state["model"]
    where = f"{init_checkpoint(cfg.init)}: --init"
    config = state.get("config", {})
    saved = (config.get("model") if isinstance(config, dict) else None) or {}
    if not isinstance(saved, dict):
        raise TweenError(f"{where}: its config describes no network (no 'model' table)")
    bad = [
        n for n, t in init.items() if torch.is_tensor(t) and t.is_floating_point() and not t.isfinite().all()
    ]
    if bad:  # a diverged run: every step from it is NaN
        raise TweenError(
            f"{where}: weight {bad[0]} holds values that are not finite (the run it comes from diverged)"
        )
    try:  # the weights must be the network's: refused before the run's folder is made
        cfg = replace(cfg, model=inherit_model(cfg.model, saved))
        if cfg.model.delta and not saved.get("delta", False):
            init = to_delta_inputs(init, cfg.model.n_joints)
        check_network_size(cfg.model, init, where)  # before a network of the config's size is made
        net = Generator(cfg.model)
        net.load_state_dict({**net.state_dict(), **init})
    except (TypeError, ValueError, KeyError, RuntimeError, AttributeError) as e:
        lines = [t.strip() for t in str(e).splitlines() if t.strip() and not t.strip().endswith(":")]
        why = lines[0][:160] if lines else type(e).__name__
        raise TweenError(
            f"{where}: its weights are not those of the network its config describes ({why})"
        ) from None
    check_partial(cfg)
    return cfg, init


#: Bounds on the network an --init config describes: checked before any weight is allocated.
MAX_LAYERS = 32
MAX_WEIGHTS = 500_000_000  # ~2 GB of float32; the shipped models have a few million


def check_network_size(model: GeneratorConfig, weights: dict, where: str) -> None:
    """The network ``model`` describes, built on the meta device (no memory) and given
    ``weights``: their shapes must be its own (ValueError, RuntimeError as when loaded), and
    it must be of a reasonable size (TweenError naming ``where``): a config of width 10**6
    would otherwise allocate gigabytes before the weights were compared."""
    if len(model.levels) + len(model.bottleneck_dilations) > MAX_LAYERS:
        raise TweenError(f"{where}: its config describes a network of over {MAX_LAYERS} layers")
    check_weight_count(Generator, model, weights, where)


def check_weight_count(cls, config, weights: dict, where: str) -> None:
    """The network ``cls(config)`` built on the meta device (no memory) and given ``weights``
    (their shapes must be its own: RuntimeError as when loaded); TweenError naming ``where``
    when it holds over MAX_WEIGHTS weights."""
    with torch.device("meta"):
        net = cls(config)
    net.load_state_dict({**net.state_dict(), **weights}, assign=True)
    n = sum(p.numel() for p in net.parameters())
    if n > MAX_WEIGHTS:
        raise TweenError(
            f"{where}: its config describes a network of {n:,} weights (at most {MAX_WEIGHTS:,})"
        )


def _optimiser(cfg: TrainConfig, model: Generator, init: dict | None):
    """AdamW and its one-cycle schedule over the weights the run trains (``--freeze``: the
    add-on modules only), those an --init checkpoint lacks at ``--new-lr`` times the rate."""
    # Weights an --init checkpoint lacks (a DNA encoder or adapter added to it) start from
    # scratch beside trained ones: Adam moves every weight by about the learning rate a step,
    # so they get a larger one to catch up. Continuing a model that has them already treats
    # them as trained.
    fresh = {n for n, _ in model.named_parameters() if init is not None and n not in init}
    trainable = dict(model.named_parameters())
    if cfg.freeze:
        # Only the add-on modules train; the trunk stays bit for bit as --init left it.
        addons = {id(p) for m in (model.dna, model.adapter) if m is not None for p in m.parameters()}
        if not addons:
            raise ValueError("freeze trains only the add-on modules: give --dna or --key-adapter")
        for n, p in list(trainable.items()):
            if id(p) not in addons:
                p.requires_grad_(False)
                del trainable[n]
    old = [p for n, p in trainable.items() if n not in fresh]
    new = [p for n, p in trainable.items() if n in fresh]
    groups = [{"params": ps, "lr": lr} for ps, lr in ((old, cfg.lr), (new, cfg.lr * cfg.new_lr)) if ps]
    opt = torch.optim.AdamW(groups, lr=cfg.lr, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(
        opt,
        max_lr=[g["lr"] for g in groups],
        total_steps=cfg.steps,
        pct_start=min(max(0.05, 3 / cfg.steps), 0.5),  # (runs of under 6 steps: a smoke test)
    )
    return opt, sched


def _position_weights(cfg: TrainConfig, clips, skel, dev) -> torch.Tensor:
    """(J, 3) weights of the position losses: 1, or with ``--pos-zscore`` 10 cm / std per
    coordinate (a coordinate that varies little, a joint's height, counts as much as its
    spread says, as in the benchmark's L2P). A studio's own takes weigh by their own spread
    (they need not come with Bandai's)."""
    if not cfg.pos_zscore:
        return torch.ones(len(skel), 3).to(dev)
    from pipeline.data.protocol import position_stats

    _, std = position_stats(clips if cfg.data_pack or cfg.data else load_split("train"))
    return torch.from_numpy(POS_SCALE / std.reshape(len(skel), 3)).float().to(dev)


def _supervised_losses(
    cfg: TrainConfig, model: Generator, b: dict, skel, pos_w, dev
) -> tuple[dict, torch.Tensor]:
    """The seven supervised losses of one batch (rotations, positions, root, velocity, foot
    contacts, batch regularisation, motion DNA) and the predicted joint positions (the
    adversarial step's fake)."""
    import roma

    from pipeline.motion.fk import fk_torch

    between = b["between"].numpy()
    x = b["feats"].to(dev)
    dna, dna_on = (b["dna"].to(dev), b["dna_weight"].to(dev)) if "dna" in b else (None, None)
    out = model(x, dna, dna_on)
    mats, proot, clog = decode(out, x, len(skel))
    gt_rot = b["crot"].to(dev).float()
    q_pred = roma.rotmat_to_unitquat(mats)
    if "match_w" in b:
        ak = b["all_keys"].to(dev)
        q_pred, proot = match_partial_keys(
            q_pred, proot, gt_rot[:, ak], b["croot"].to(dev).float()[:, ak], ak, b["match_w"].to(dev)
        )
        mats = roma.unitquat_to_rotmat(q_pred)
    gt_mats = roma.unitquat_to_rotmat(gt_rot)
    m = torch.from_numpy(between).to(dev)
    _, ppos = fk_torch(q_pred, proot, skel.parents, skel.offsets)
    gt_pos = b["gpos"].to(dev).float()
    fw = b["frame_weight"].to(dev)[None, :, None]
    fv = torch.maximum(fw[:, 1:], fw[:, :-1])[..., None]
    # (In this order: the autograd graph's, and with it the order gradients are summed in.)
    losses = {"rot": ((mats - gt_mats).abs() * fw[..., None, None])[:, m].mean()}
    losses["pos"] = ((ppos - gt_pos).abs() * pos_w * fw[..., None])[:, m].mean() / POS_SCALE
    losses["root"] = ((proot - b["croot"].to(dev).float()).abs() * fw)[:, m].mean() / POS_SCALE
    moving = torch.from_numpy(between[1:] | between[:-1]).to(dev)
    vel = ((ppos[:, 1:] - ppos[:, :-1]) - (gt_pos[:, 1:] - gt_pos[:, :-1])).abs() * fv
    losses["vel"] = vel[:, moving].mean() / POS_SCALE
    losses["contact"] = torch.nn.functional.binary_cross_entropy_with_logits(
        clog[:, m], b["contacts"].to(dev)[:, m]
    )
    losses["br"] = batch_regularisation(model.res_layers())
    no_dna = dna is None
    losses["dna"] = torch.zeros((), device=dev) if no_dna else dna_loss(ppos, dna, dna_on, m, skel)
    return losses, ppos


#: Options that say how a run goes, not what it trains: a resumed run may change them.
HOW_IT_RUNS = frozenset({"threads", "checkpoint_minutes", "device", "workers"})


def _absolute_paths(cfg: TrainConfig) -> TrainConfig:
    """``cfg`` with its path options absolute, as the checkpoint records them."""
    paths = {f.name: os.path.abspath(getattr(cfg, f.name)) for f in fields(cfg)
             if f.metadata.get("path") and isinstance(getattr(cfg, f.name), str)}  # fmt: skip
    return replace(cfg, **paths)


def _run_config(cfg: TrainConfig, dev, ckpt: Path) -> tuple[TrainConfig, dict | None]:
    """The run's config and its --init weights: paths absolute (an export from another folder
    reads the same --data and --init), the --init network's shape (and check_partial), and
    checked against the checkpoint it resumes."""
    cfg, init = _with_init(_absolute_paths(cfg), dev)
    _check_same_run(cfg, ckpt)
    return cfg, init


def _check_same_run(cfg: TrainConfig, ckpt: Path) -> None:
    """TweenError when the run folder's checkpoint was trained with other options than these
    (``--steps``, ``--data``, ``--init``, the network...): resumed, the run would mix two
    trainings under one config (and a longer ``--steps`` outruns its learning-rate schedule)."""
    if not ckpt.exists():
        return
    saved = read_checkpoint(ckpt, "the run's checkpoint", "cpu", "; remove it to start this run afresh").get(
        "config"
    )
    now = asdict(cfg)
    for f in fields(cfg):  # a path recorded relative (older runs) is the same path from here
        if f.metadata.get("path") and saved and isinstance(saved.get(f.name), str):
            saved = {**saved, f.name: os.path.abspath(saved[f.name])}
    differ = [
        k for k in now if k not in HOW_IT_RUNS and k in (saved or {}) and _same(saved[k]) != _same(now[k])
    ]
    if differ:
        shown = "; ".join(f"{k}: {saved[k]!r} there, {now[k]!r} now" for k in differ[:3])
        more = f" and {len(differ) - 3} more" if len(differ) > 3 else ""
        raise TweenError(
            f"{ckpt}: this run folder holds a training with other options ({shown}{more}); "
            "resume it with its own options, or give another --out"
        )


def _same(v):
    """A config value as compared across a resume (tuples and lists alike)."""
    if isinstance(v, dict):
        return {k: _same(x) for k, x in v.items()}
    return [_same(x) for x in v] if isinstance(v, list | tuple) else v


def _start(cfg: TrainConfig, model, opt, sched, init: dict | None, ckpt: Path, dev):
    """(step, seconds so far, discriminator and its optimiser or None) where the run starts:
    its checkpoint's, resumed into ``model``, ``opt`` and ``sched``; else step 0 from the
    --init weights (``init``) or from scratch."""
    if not ckpt.exists():
        if init is not None:
            model.load_state_dict({**model.state_dict(), **init})  # new modules keep their fresh start
            print(f"initialised from {cfg.init}", file=sys.stderr)
        return 0, 0.0, None, None
    state = read_checkpoint(ckpt, "the run's checkpoint", dev, "; remove it to start this run afresh")
    model.load_state_dict(state["model"])
    opt.load_state_dict(state["opt"])
    sched.load_state_dict(state["sched"])
    disc, d_opt = None, None
    if "disc" in state:
        disc, d_opt = make_discriminator(cfg, dev)
        disc.load_state_dict(state["disc"])
        d_opt.load_state_dict(state["d_opt"])
    print(f"resumed {ckpt} at step {state['step']}", file=sys.stderr)
    return state["step"], state["elapsed"], disc, d_opt


def _discriminated(b: dict, ppos: torch.Tensor, dev) -> tuple[torch.Tensor, torch.Tensor]:
    """(real, fake): what the discriminator sees of a batch, root-relative joint positions;
    the fake with the keys re-inserted (§3.3)."""
    gt_pos = b["gpos"].to(dev).float()
    kmask = torch.zeros(int(b["L"]), dtype=torch.bool, device=dev)
    kmask[b["keys"].numpy()] = True
    fake = rel_positions(torch.where(kmask[None, :, None, None], gt_pos, ppos))
    return rel_positions(gt_pos), fake


def _step(cfg: TrainConfig, model, opt, sched, gan, b: dict, skel, pos_w, dev):
    """One optimisation step on batch ``b``: the supervised losses, with ``gan`` (the
    discriminator and its optimiser, from ``--adv-start``) the LSGAN loss too, then the
    discriminator's own step. Returns the total loss and each part (``adv`` 0 without)."""
    losses, ppos = _supervised_losses(cfg, model, b, skel, pos_w, dev)
    loss = (
        cfg.w_rot * losses["rot"]
        + cfg.w_pos * losses["pos"]
        + cfg.w_root * losses["root"]
        + cfg.w_vel * losses["vel"]
        + cfg.w_contact * losses["contact"]
        + cfg.w_br * losses["br"]
        + cfg.w_dna * losses["dna"]
    )
    losses["adv"] = torch.zeros((), device=dev)
    if gan is not None:
        real, fake = _discriminated(b, ppos, dev)
        losses["adv"] = g_loss(gan[0](fake))
        loss = loss + cfg.w_adv * losses["adv"]
    opt.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
    opt.step()
    sched.step()
    if gan is not None:
        disc, d_opt = gan
        ld = d_loss(disc(real), disc(fake.detach())) + cfg.w_br * batch_regularisation(disc.res_layers())
        d_opt.zero_grad(set_to_none=True)
        ld.backward()
        d_opt.step()
    return loss, losses


def resumed_log(path: Path, step: int):
    """The run's log ``path`` (a JSON line every LOG_EVERY steps) open to append to, the run
    starting at ``step``: the lines of later steps, which a stopped run wrote after its last
    checkpoint and this one logs again (they were in the log twice), are dropped first, the
    log rewritten whole or not at all; so is a line that is not a whole record (one a killed
    run was writing)."""
    if path.exists():
        if (odd := not_a_file(path, "training log")) is not None:  # a pipe would block the read
            raise TweenError(f"{path}: {odd}; remove it to resume the run")
        lines = path.read_bytes().splitlines(keepends=True)
        keep = [line for line in lines if (s := _logged_step(line)) is not None and s <= step]
        if len(keep) < len(lines):
            write_bytes(path, b"".join(keep))
    return path.open("a")


def _logged_step(line: bytes) -> int | None:
    """The step a line of a run's log records; None for a line that is not a whole record."""
    try:
        step = json.loads(line)["step"]
    except (ValueError, TypeError, KeyError, RecursionError):  # (a damaged line: "[[[[...")
        return None
    ok = isinstance(step, int) and not isinstance(step, bool) and line.endswith(b"\n")
    return step if ok else None


def _log_line(log, bar, step: int, loss, losses: dict, max_gap, seconds: float) -> None:
    """A line of train_log.jsonl (the step's losses), and the progress bar's figures."""
    parts = ("rot", "pos", "root", "vel", "contact", "br", "adv", "dna")
    rec = {"step": step, "loss": loss.item(), **{k: losses[k].item() for k in parts},
           "max_gap": max_gap, "t": seconds}  # fmt: skip
    log.write(json.dumps(rec) + "\n")
    log.flush()
    bar.set_postfix(loss=f"{rec['loss']:.4f}", pos=f"{rec['pos']:.4f}", gap=max_gap)


def train(cfg: TrainConfig, out_dir: Path) -> Path:
    """Train the generator (``cfg``) into ``out_dir`` (generator.pt, train_log.jsonl),
    resuming its checkpoint there; returns the checkpoint. The loop: a batch, the supervised
    losses, from ``--adv-start`` the LSGAN step, a log line every LOG_EVERY steps, a checkpoint
    every ``--checkpoint-minutes``."""
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    dev = torch.device(cfg.device)
    skel = bandai_skeleton()
    feet = [skel.index(n) for n in FOOT_JOINTS]
    cfg, init = _run_config(cfg, dev, out_dir / "generator.pt")  # before any data is read
    clips = training_clips(cfg)
    out_dir.mkdir(parents=True, exist_ok=True)  # the data and --init read first: a refusal writes nothing
    model = Generator(cfg.model).to(dev)
    opt, sched = _optimiser(cfg, model, init)
    ckpt = out_dir / "generator.pt"
    step, elapsed, disc, d_opt = _start(cfg, model, opt, sched, init, ckpt, dev)
    pos_w = _position_weights(cfg, clips, skel, dev)
    log = resumed_log(out_dir / "train_log.jsonl", step)
    t_start, t_ckpt = time.time() - elapsed, time.time()

    def save(path=ckpt):
        state = {
            "model": model.state_dict(),
            "opt": opt.state_dict(),
            "sched": sched.state_dict(),
            "step": step,
            "elapsed": time.time() - t_start,
            "config": asdict(cfg),
        }
        if disc is not None:
            state["disc"], state["d_opt"] = disc.state_dict(), d_opt.state_dict()
        save_torch(state, path)  # a temporary of its own: not another run's half-written file

    bar = tqdm(total=cfg.steps, initial=step, file=sys.stderr, desc="generator", mininterval=interval())
    batches = batches_from(cfg, clips, skel, feet, step)
    model.train()
    while step < cfg.steps:
        b = next(batches)
        if b is None:
            step += 1
            continue
        adversarial = cfg.adv_start is not None and step >= cfg.adv_start
        if adversarial and disc is None:
            disc, d_opt = make_discriminator(cfg, dev)
            save(out_dir / "generator_supervised.pt")
        loss, losses = _step(
            cfg, model, opt, sched, (disc, d_opt) if adversarial else None, b, skel, pos_w, dev
        )
        step += 1
        bar.update(1)
        if step % LOG_EVERY == 0:
            _log_line(log, bar, step, loss, losses, b["max_gap"], time.time() - t_start)
        if time.time() - t_ckpt > cfg.checkpoint_minutes * 60:
            save()
            t_ckpt = time.time()
    save()
    bar.close()
    return ckpt
