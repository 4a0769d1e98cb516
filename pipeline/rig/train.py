"""Training a per-rig GANimator from one clip: coarse-to-fine pyramid, groups of two levels.

Per the paper (and the official code where the paper is silent; see
``docs/rig.md``): WGAN-GP (λ_gp = 1) with 5 discriminator steps, then one generator step
on −D(fake) + 5·L_con, then one separate reconstruction step on 50·L1; Adam at 1e-4;
noise shared across channels with a per-level amplitude from the data; a fixed z* for the
reconstruction; levels trained two at a time with the coarser ones frozen.

Checkpoints go to ``OUT/checkpoints/``: ``state.pt`` (everything needed to resume, written
every ``ckpt_every`` iterations and at the end of each group) and ``group{k}.pt`` (the
generators once group k is done). Re-running the same command resumes; on CPU the result
is the same bit for bit for a seed and thread count whether or not it was interrupted.
"""

from __future__ import annotations

import hashlib
import json
import math
import pickle
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from pipeline.atomic import save_torch, write_bytes
from pipeline.errors import TweenError
from pipeline.inputs import not_a_file, refused_for_safety
from pipeline.motion.clip import Motion
from pipeline.rig.options import check_device
from pipeline.rig.progress import Progress, ProgressBar, ProgressCallback
from pipeline.rig.represent import RigSpec, encode, make_spec, pyramid_lengths, resample_linear
from pipeline.rig.topology import neighbourhoods
from pipeline.staging import refuse_read_only

LAMBDA_GP = 1.0
LAMBDA_REC = 50.0
LAMBDA_CON = 5.0


@dataclass(frozen=True)
class Schedule:
    """How long and how wide. ``hidden`` are per-vertex widths when ``per_vertex``."""

    name: str
    iters: int  # outer iterations per group of levels
    hidden: tuple[float, float, float]
    per_vertex: bool
    ratio: float = 1 / 5  # coarsest length = ratio · T
    group: int = 2
    d_steps: int = 5
    lr: float = 1e-4
    ckpt_every: int = 100

    def widths(self, V: int) -> tuple[int, int, int]:
        return tuple(int(math.ceil((h * V if self.per_vertex else h) / V) * V) for h in self.hidden)


SCHEDULES = {
    # The official code's defaults: 15k iterations per group, channels 128/256/256.
    "paper": Schedule("paper", 15000, (128, 256, 256), False),
    # About an hour on 2 CPU cores for a ~750-frame clip of ~30 joints (see docs/rig.md).
    "reduced": Schedule("reduced", 1500, (3, 3, 3), True),
    # Seconds, for tests.
    "tiny": Schedule("tiny", 30, (2, 2, 2), True, lr=1e-3, ckpt_every=10),
}


#: What :meth:`Trainer.save` writes into ``state.pt``.
STATE_KEYS = (
    "stamp",
    "group_done",
    "iteration",
    "G",
    "D",
    "opt_g",
    "opt_d",
    "rng",
    "cuda_rng",
    "log",
    "wall",
)


class TrainError(TweenError):
    pass


@dataclass
class TrainConfig:
    source: str
    out: str
    skeleton: str | None = None
    frames: tuple[int, int] | None = None
    fps: float | None = None  # None: 30 when the source is faster, else the source's rate
    schedule: str = "reduced"
    iters: int | None = None  # overrides the schedule's iterations per group
    ratio: float | None = None  # overrides the schedule's coarsest-level ratio
    ckpt_every: int | None = None  # overrides the schedule's checkpoint interval
    contacts: list[str] | None = None  # contact joint names; None: from the clip's floor contacts
    seed: int = 0
    threads: int = 1
    device: str = "cpu"
    licence: str = "unknown"
    credit: str | None = None  # attribution line for the model card
    name: str | None = None
    checkpoints: str | None = None  # default: OUT/checkpoints
    extra: dict = field(default_factory=dict)

    def resolved_schedule(self) -> Schedule:
        if self.schedule not in SCHEDULES:
            raise TrainError(f"--schedule {self.schedule!r}: choose one of {', '.join(SCHEDULES)}")
        s = SCHEDULES[self.schedule]
        kw = asdict(s)
        if self.iters is not None:
            kw["iters"] = int(self.iters)
        if self.ratio is not None:
            kw["ratio"] = float(self.ratio)
        if self.ckpt_every is not None:
            kw["ckpt_every"] = int(self.ckpt_every)
        kw["hidden"] = tuple(kw["hidden"])
        return Schedule(**kw)


def prepare_motion(cfg: TrainConfig) -> Motion:
    """The training clip: read, cut to ``frames`` and resampled to the training rate."""
    from pipeline.motion.clip import resample
    from pipeline.rig.source import load_rig_source

    motion = load_rig_source(cfg.source, cfg.skeleton, cfg.frames)
    fps = cfg.fps or (30.0 if motion.fps > 30.5 else motion.fps)
    return resample(motion, fps)


def spec_for(motion: Motion, contact_names: list[str] | None) -> RigSpec:
    if contact_names is None:
        return make_spec(motion)
    try:
        idx = [motion.skeleton.index(n) for n in contact_names]
    except KeyError as e:
        raise TrainError(f"--contacts: {e.args[0]} (joints: {', '.join(motion.skeleton.names)})") from None
    for j in idx:
        p = motion.skeleton.parents[j]
        if p < 0 or motion.skeleton.parents[p] < 0:
            raise TrainError(f"--contacts: {motion.skeleton.names[j]!r} needs a parent and a grandparent")
    return make_spec(motion, sorted(idx))


def level_targets(feat: np.ndarray, lengths: list[int]) -> list[np.ndarray]:
    return [resample_linear(feat, n) for n in lengths]


def noise_amplitudes(targets: list[np.ndarray]) -> list[float]:
    """RMS of what each level adds to the upsampled coarser level (level 1: of itself)."""
    amps = [float(np.sqrt(np.mean(targets[0] ** 2)))]
    for i in range(1, len(targets)):
        up = resample_linear(targets[i - 1], targets[i].shape[-1])
        amps.append(float(np.sqrt(np.mean((targets[i] - up) ** 2))))
    return amps


def _groups(n_levels: int, size: int) -> list[list[int]]:
    return [list(range(a, min(a + size, n_levels))) for a in range(0, n_levels, size)]


def _stamp(cfg: TrainConfig, sched: Schedule, feat: np.ndarray, spec: RigSpec) -> dict:
    """What must match for a checkpoint to be resumed."""
    h = hashlib.sha256(np.ascontiguousarray(feat).tobytes()).hexdigest()[:16]
    return {
        "data": h,
        "schedule": {k: v for k, v in asdict(sched).items() if k != "ckpt_every"},
        "seed": cfg.seed,
        "contacts": [spec.skeleton.names[j] for j in spec.contacts],
        "device": cfg.device,
        # On CPU the weights depend on the thread count (torch's reductions split by thread).
        "threads": max(1, int(cfg.threads)),
    }


class Trainer:
    """Holds the pyramid's networks and trains it group by group."""

    def __init__(self, cfg: TrainConfig, motion: Motion | None = None, quiet: bool = False):
        import torch

        from pipeline.rig.networks import ContactFK, LevelDiscriminator, LevelGenerator

        self.cfg = cfg
        self.quiet = quiet
        self.sched = cfg.resolved_schedule()
        torch.set_num_threads(max(1, int(cfg.threads)))
        check_device(cfg.device, here=True)
        self.device = torch.device(cfg.device)
        self.motion = motion if motion is not None else prepare_motion(cfg)
        self.spec = spec_for(self.motion, cfg.contacts)
        feat, self.begin = encode(self.motion, self.spec)
        T = feat.shape[-1]
        self.lengths = pyramid_lengths(T, self.sched.ratio)
        if self.lengths[0] < 8:
            raise TrainError(
                f"{cfg.source}: {T} frames give a coarsest level of {self.lengths[0]} frames; "
                "use a longer clip or a larger --ratio"
            )
        targets = level_targets(feat, self.lengths)
        self.amps = noise_amplitudes(targets)
        self.nb = neighbourhoods(self.spec.skeleton.parents, self.spec.contacts)
        V = len(self.nb)
        self.F = 6 * V
        self.hidden = self.sched.widths(V)
        self.stamp = _stamp(cfg, self.sched, feat, self.spec)
        torch.manual_seed(cfg.seed)
        n = len(self.lengths)
        self.G = [LevelGenerator(self.nb, self.F, self.hidden).to(self.device) for _ in range(n)]
        self.D = [LevelDiscriminator(self.nb, self.F, self.hidden).to(self.device) for _ in range(n)]
        gen = torch.Generator().manual_seed(cfg.seed + 1)
        self.z_star = torch.randn(1, self.F, self.lengths[0], generator=gen).to(self.device)
        self.real = [torch.from_numpy(t)[None].to(self.device) for t in targets]
        self.fk = ContactFK(
            self.spec.skeleton.parents, self.spec.skeleton.offsets, self.spec.contacts, self.spec.scale
        ).to(self.device)
        self.groups = _groups(n, self.sched.group)
        self.log: list[dict] = []
        self.group_done = 0
        self.iteration = 0
        self.wall = [0.0] * len(self.groups)

    # -- the pyramid --------------------------------------------------------------------
    def noise(self, i: int):
        import torch

        return torch.randn(1, 1, self.lengths[i], device=self.device) * self.amps[i]

    def chain(self, top: int, first_trained: int):
        """Random-mode outputs of levels 0..top (fresh noise at every level)."""
        import torch

        from pipeline.rig.networks import upsample

        outs = []
        prev = None
        for i in range(top + 1):
            up = (
                torch.zeros(1, self.F, self.lengths[0], device=self.device)
                if prev is None
                else upsample(prev, self.lengths[i])
            )
            z = self.noise(i)
            if i < first_trained:
                with torch.no_grad():
                    prev = self.G[i](up, z)
            else:
                prev = self.G[i](up, z)
            outs.append(prev)
        return outs

    def reconstruction(self, top: int):
        """Reconstruction-mode outputs: z* at level 1, no noise above (levels 0..top)."""
        import torch

        from pipeline.rig.networks import upsample

        outs = []
        prev = None
        for i in range(top + 1):
            if prev is None:
                up, z = torch.zeros_like(self.z_star), self.z_star
            else:
                up = upsample(prev, self.lengths[i])
                z = torch.zeros(1, 1, self.lengths[i], device=self.device)
            prev = self.G[i](up, z)
            outs.append(prev)
        return outs

    def gradient_penalty(self, D, real, fake):
        import torch

        alpha = torch.rand(1, device=self.device)
        x = (alpha * real + (1 - alpha) * fake).requires_grad_(True)
        out = D(x)
        (grad,) = torch.autograd.grad(out.sum(), x, create_graph=True)
        return ((grad.norm(dim=1) - 1) ** 2).mean()

    # -- checkpoints ---------------------------------------------------------------------
    @property
    def ckpt_dir(self) -> Path:
        return Path(self.cfg.checkpoints or Path(self.cfg.out) / "checkpoints")

    def _opts(self, group: list[int]):
        import torch

        lr = self.sched.lr
        g = torch.optim.Adam([p for i in group for p in self.G[i].parameters()], lr=lr)
        d = torch.optim.Adam([p for i in group for p in self.D[i].parameters()], lr=lr)
        return g, d

    def save(self, opt_g, opt_d) -> None:
        import torch

        self.ckpt_dir.mkdir(parents=True, exist_ok=True)
        state = {
            "stamp": self.stamp,
            "group_done": self.group_done,
            "iteration": self.iteration,
            "G": [g.state_dict() for g in self.G],
            "D": [d.state_dict() for d in self.D],
            "opt_g": opt_g.state_dict() if opt_g else None,
            "opt_d": opt_d.state_dict() if opt_d else None,
            "rng": torch.get_rng_state(),
            "cuda_rng": torch.cuda.get_rng_state_all() if self.device.type == "cuda" else None,
            "log": self.log,
            "wall": self.wall,
        }
        save_torch(state, self.ckpt_dir / "state.pt")  # a full disk: one line, the last one kept

    def load(self) -> dict | None:
        import torch

        path = self.ckpt_dir / "state.pt"
        if not path.exists():
            return None
        state = self._read_state(path)
        state["stamp"]["schedule"].pop("ckpt_every", None)  # how often to save is not part of the run
        state["stamp"].setdefault("threads", self.stamp["threads"])  # written before threads were kept
        if state["stamp"] != self.stamp:
            diff = [k for k in self.stamp if state["stamp"].get(k) != self.stamp[k]]
            if diff == ["threads"]:
                n = state["stamp"]["threads"]
                raise TrainError(
                    f"{path}: this training ran with --threads {n}; resume it with --threads {n} "
                    "(its weights depend on the thread count), or use another --out"
                )
            raise TrainError(
                f"{path}: a run with other {', '.join(diff)} is in this folder; use another --out"
            )
        for g, s in zip(self.G, state["G"], strict=True):
            g.load_state_dict(s)
        for d, s in zip(self.D, state["D"], strict=True):
            d.load_state_dict(s)
        self.group_done, self.iteration = state["group_done"], state["iteration"]
        self.log, self.wall = state["log"], state["wall"]
        # map_location moved every tensor to the device; RNG states must be CPU byte tensors.
        torch.set_rng_state(state["rng"].cpu())
        if state["cuda_rng"] is not None:
            torch.cuda.set_rng_state_all([s.cpu() for s in state["cuda_rng"]])
        return state

    def _read_state(self, path: Path) -> dict:
        """``state.pt`` as :meth:`save` wrote it; one line naming it when it is damaged."""
        import torch

        if path.exists() and (odd := not_a_file(path, "checkpoint")) is not None:
            raise TrainError(f"{path}: cannot read the checkpoint: {odd}")  # a pipe would block torch.load
        try:
            # weights_only: tensors and plain values only; a crafted state.pt runs no code.
            state = torch.load(path, map_location=self.device, weights_only=True)
        except OSError as e:
            raise TrainError(f"{path}: cannot read the checkpoint: {e.strerror or e}") from None
        except pickle.UnpicklingError as e:
            if not refused_for_safety(path, e):  # a cut or foreign pickle: damaged, below
                state = None
            else:  # weights_only refused what it names (os.system, a class): not damage, a danger
                raise TrainError(
                    f"{path}: the training checkpoint holds something other than tensors and plain "
                    f"values and was refused for safety (nothing in it was run); remove {self.ckpt_dir} "
                    "to start this training over"
                ) from None
        except Exception:  # torch.load's errors for a cut, empty or foreign file are many kinds
            state = None
        if (
            not isinstance(state, dict)
            or any(k not in state for k in STATE_KEYS)
            or not isinstance(state["stamp"], dict)
            or not isinstance(state["stamp"].get("schedule"), dict)
        ):
            raise TrainError(
                f"{path}: the training checkpoint is damaged (cut short, empty or not one `train-rig` wrote); "
                f"remove {self.ckpt_dir} to start this training over"
            )
        return state

    # -- training ------------------------------------------------------------------------
    def train(self, on_progress: ProgressCallback | None = None, resumed: dict | None = None) -> None:
        """Trains every group not done yet (``resumed``: :meth:`load`'s state, if read); ``on_progress``
        gets a :class:`Progress` at each group's start and each iteration (one if nothing is left)."""
        state = resumed if resumed is not None else self.load()
        iters, n = self.sched.iters, len(self.lengths)
        steps = len(self.groups) * iters
        t_session, step_session = time.perf_counter(), self.group_done * iters + self.iteration
        last: Progress | None = None

        def report(gi: int, it: int, losses: dict) -> None:
            nonlocal last
            if on_progress is None:
                return
            step = gi * iters + it
            done_here, took = step - step_session, time.perf_counter() - t_session
            levels = tuple(i + 1 for i in self.groups[gi])
            last = Progress(
                stage=f"levels {levels[0]}-{levels[-1]}/{n}",
                step=step,
                steps=steps,
                loss={k: float(v) for k, v in losses.items() if k not in ("group", "iteration")},
                elapsed_s=round(sum(self.wall), 3),
                eta_s=round(took / done_here * (steps - step), 1) if done_here > 0 else None,
                stage_step=it,
                stage_steps=iters,
                group_levels=levels,
                n_levels=n,
            )
            on_progress(last)

        for gi, group in enumerate(self.groups):
            if gi < self.group_done:
                continue
            opt_g, opt_d = self._opts(group)
            if state is not None and state["opt_g"] is not None and self.iteration > 0:
                opt_g.load_state_dict(state["opt_g"])
                opt_d.load_state_dict(state["opt_d"])
            state = None
            first, top = group[0], group[-1]
            for i in range(first):
                self.G[i].requires_grad_(False)
            report(gi, self.iteration, {})
            t0 = time.perf_counter()
            wall0 = self.wall[gi]
            while self.iteration < iters:
                losses = self.step(group, opt_g, opt_d)
                self.iteration += 1
                self.wall[gi] = wall0 + time.perf_counter() - t0
                if self.iteration % 10 == 0 or self.iteration in (1, iters):
                    self.log.append({"group": gi, "iteration": self.iteration, **losses})
                report(gi, self.iteration, losses)
                if self.iteration % self.sched.ckpt_every == 0 and self.iteration < iters:
                    self.save(opt_g, opt_d)
            self.group_done, self.iteration = gi + 1, 0
            self.save(None, None)
            save_torch([self.G[i].state_dict() for i in range(top + 1)], self.ckpt_dir / f"group{gi}.pt")
        if last is None or not last.done:  # resumed after the end: still say where it stands
            report(len(self.groups) - 1, iters, self.log[-1] if self.log else {})

    def step(self, group: list[int], opt_g, opt_d) -> dict:
        from pipeline.rig.networks import contact_loss

        first, top = group[0], group[-1]
        J = len(self.spec.skeleton)
        # Discriminators: WGAN-GP, d_steps times on fresh fakes.
        for i in group:
            self.D[i].requires_grad_(True)
        for _ in range(self.sched.d_steps):
            import torch

            with torch.no_grad():
                fakes = self.chain(top, first)
            loss_d = 0.0
            for i in group:
                D, real, fake = self.D[i], self.real[i], fakes[i]
                wd = -D(real).mean() + D(fake).mean()
                loss_d = loss_d + 0.5 * wd + LAMBDA_GP * self.gradient_penalty(D, real, fake)
            opt_d.zero_grad(set_to_none=True)
            loss_d.backward()
            opt_d.step()
        # Generators: adversarial + contact consistency.
        for i in group:
            self.D[i].requires_grad_(False)
        fakes = self.chain(top, first)
        adv = sum(-self.D[i](fakes[i]).mean() for i in group)
        con = sum(contact_loss(self.fk, fakes[i], J) for i in group)
        opt_g.zero_grad(set_to_none=True)
        (adv + LAMBDA_CON * con).backward()
        opt_g.step()
        # Reconstruction: a separate step.
        recs = self.reconstruction(top)
        import torch

        rec = sum(torch.nn.functional.l1_loss(recs[i], self.real[i]) for i in group)
        opt_g.zero_grad(set_to_none=True)
        (LAMBDA_REC * rec).backward()
        opt_g.step()
        return {k: float(v.detach()) for k, v in (("d", loss_d), ("adv", adv), ("con", con), ("rec", rec))}

    # -- summary -------------------------------------------------------------------------
    def summary(self) -> dict:
        from pipeline.rig.networks import count_parameters

        g = [count_parameters(x) for x in self.G]
        d = [count_parameters(x) for x in self.D]
        per_group = []
        for gi, grp in enumerate(self.groups):
            last = [e for e in self.log if e["group"] == gi]
            per_group.append(
                {
                    "levels": [i + 1 for i in grp],
                    "iterations": self.sched.iters if gi < self.group_done else self.iteration,
                    "wall_s": round(self.wall[gi], 1),
                    "final_losses": {
                        k: round(v, 5) for k, v in last[-1].items() if k not in ("group", "iteration")
                    }
                    if last
                    else {},
                }
            )
        return {
            "schedule": asdict(self.sched),
            "hidden_channels": list(self.hidden),
            "channels": self.F,
            "lengths": self.lengths,
            "noise_amplitudes": [round(a, 6) for a in self.amps],
            "groups": per_group,
            "wall_s": round(sum(self.wall), 1),
            "threads": self.cfg.threads,
            "device": self.cfg.device,
            "seed": self.cfg.seed,
            "generator_params": {"stored": sum(x[0] for x in g), "effective": sum(x[1] for x in g)},
            "discriminator_params": {"stored": sum(x[0] for x in d), "effective": sum(x[1] for x in d)},
        }


def train(
    cfg: TrainConfig,
    motion: Motion | None = None,
    quiet: bool = False,
    on_progress: ProgressCallback | None = None,
) -> Trainer:
    """Train (or resume) into ``cfg.out``; returns the trainer with every level trained.

    ``on_progress`` gets the run's :class:`~pipeline.rig.progress.Progress` records; without
    one, a bar on stderr shows them unless ``quiet``."""
    _check_checkpoints(cfg)
    tr = Trainer(cfg, motion, quiet)  # reads and checks the clip before anything is written
    resumed = tr.load()  # and the checkpoint it resumes (another run's, a damaged one: refused)
    tr.ckpt_dir.mkdir(parents=True, exist_ok=True)
    config = json.dumps({k: v for k, v in asdict(cfg).items()}, indent=1, default=str)
    write_bytes(tr.ckpt_dir / "train_config.json", config.encode())
    if on_progress is not None or quiet:
        tr.train(on_progress, resumed)
    else:
        with ProgressBar(sys.stderr) as bar:
            tr.train(bar, resumed)
    return tr


def _check_checkpoints(cfg: TrainConfig) -> None:
    """A ``--checkpoints`` that names a file, or a folder that cannot be written, is refused
    naming the option (before: the file's name and "File exists", as if it were the clip)."""
    if cfg.checkpoints is None:
        return
    path = Path(cfg.checkpoints)
    if path.exists() and not path.is_dir():
        raise TrainError(f"{path}: --checkpoints names a file, not a folder")
    refuse_read_only(path, "--checkpoints")
