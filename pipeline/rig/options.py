"""The options of a per-rig training, each declared once.

A :class:`TrainRigOptions` field carries its flag and help: ``tween train-rig`` (in this
process) and ``tween submit-train-rig`` (the farm) offer the same options
(:func:`with_train_rig_options`), and the farm task turns a job's options back into the
``tween train-rig`` command line from the same fields (:func:`command_args`).
"""

from __future__ import annotations

import re
from dataclasses import asdict, dataclass

from pipeline.errors import TweenError
from pipeline.options import MAX_TEXT, flags_of, job_args, one_line, option, path_like, with_options

SCHEDULES = ("tiny", "reduced", "paper")
MAX_SEED = 2**31 - 1


def _opt(default, flag: str, help: str):
    return option(default, flag, help=help)


def check_device(device, here: bool = False) -> None:
    """TweenError unless ``device`` names cpu or a CUDA device (cuda, cuda:N); with ``here``,
    one that torch sees on this host too (the trainers, before their minutes of work; a farm
    client checks the name alone, without torch)."""
    if not re.fullmatch(r"cpu|cuda(:\d+)?", str(device)):
        raise TweenError(f"--device {device!r}: must be cpu or cuda (cuda:N)")
    if here and device.startswith("cuda"):
        import torch

        n = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if int(device.partition(":")[2] or 0) >= n:
            raise TweenError(f"--device {device}: torch sees {n} CUDA device(s) on this host")


@dataclass
class TrainRigOptions:
    """How a rig model is trained from its clip (JSON-serialisable: it travels to the farm)."""

    skeleton: str | None = _opt(
        None, "--skeleton", "USD: the Skeleton prim path (default: the one with most joints)."
    )
    frames: str | None = _opt(
        None, "--frames", "START:STOP frame indices of the clip to learn (stop exclusive)."
    )
    fps: float | None = _opt(
        None, "--fps", "Training frame rate (default: 30 for faster sources, else the source's)."
    )
    schedule: str = _opt(
        "reduced", "--schedule", "reduced (about 1 h on 2 cores), paper (15k iterations/group), tiny (tests)."
    )
    iters: int | None = _opt(None, "--iters", "Iterations per group of levels (overrides the schedule).")
    ratio: float | None = _opt(None, "--ratio", "Coarsest level length ÷ clip length (default 1/5).")
    contacts: str | None = _opt(
        None, "--contacts", "Comma-separated contact joints (default: joints that touch the floor)."
    )
    seed: int = _opt(0, "--seed", "Training seed.")
    threads: int = _opt(1, "--threads", "torch threads; 1 is fastest on 2 shared cores.")
    device: str = _opt("cpu", "--device", "cpu or cuda (cuda:N).")
    licence: str | None = _opt(
        None, "--licence", "The clip's licence, for the model card (default: guessed)."
    )
    credit: str | None = _opt(
        None, "--credit", "Attribution for the model card (default: known assets' credit)."
    )
    name: str | None = _opt(None, "--name", "Model name (default: the --out folder's name).")
    force: bool = _opt(
        False,
        "--force",
        "Replace the finished model in --out (it stays in use until the new one is complete).",
    )

    def check(self) -> TrainRigOptions:
        """Raises TweenError (one line naming the option) unless every field is valid."""
        from pipeline.rig.source import FPS_RANGE, parse_frames

        if self.schedule not in SCHEDULES:
            raise TweenError(
                f"--schedule {self.schedule!r}: must be {', '.join(SCHEDULES[:-1])} or {SCHEDULES[-1]}"
            )
        for opt, v, lo, hi in (("--iters", self.iters, 1, 10_000_000), ("--seed", self.seed, 0, MAX_SEED),
                               ("--threads", self.threads, 1, 256)):  # fmt: skip
            if v is not None and not (isinstance(v, int) and lo <= v <= hi):
                raise TweenError(f"{opt} {v}: must be from {lo} to {hi}")
        for opt, v, lo, hi in (("--fps", self.fps, *FPS_RANGE), ("--ratio", self.ratio, 1e-3, 1.0)):
            if v is not None and not (isinstance(v, int | float) and lo <= v <= hi):  # NaN fails too
                raise TweenError(f"--{opt[2:]} {v}: must be from {lo:g} to {hi:g}")
        check_device(self.device)
        self._check_texts()
        parse_frames(self.frames)
        if self.contacts is not None and not self.contact_joints():
            raise TweenError(
                f"--contacts {self.contacts!r}: names no joint (comma-separated joint names; "
                "leave it out for the joints that touch the floor)"
            )
        return self

    def _check_texts(self) -> None:
        """An option text given empty ran with the default (``--frames ''`` learnt the whole
        clip; an empty ``--contacts`` names no joint, said in check); names, licences and
        credits go into the card and rig.json as one line; a name is no path."""
        texts = (("--frames", self.frames), ("--skeleton", self.skeleton), ("--name", self.name),
                 ("--licence", self.licence), ("--credit", self.credit))  # fmt: skip
        for flag, v in texts:
            if v is not None and (not isinstance(v, str) or not v.strip()):
                raise TweenError(f"{flag} {v!r}: empty; leave it out for the default")
        for flag, v in texts[2:]:
            if v is not None and not one_line(v):
                raise TweenError(
                    f"{flag} {v[:60]!r}: must be one line of printable text, at most {MAX_TEXT} characters"
                )
        if self.name is not None and path_like(self.name):
            raise TweenError(f"--name {self.name!r}: a model name, not a path")

    def contact_joints(self) -> list[str] | None:
        """The joint names ``--contacts`` lists (None: not given, the joints that touch the floor)."""
        return None if self.contacts is None else [c.strip() for c in self.contacts.split(",") if c.strip()]

    def as_job(self) -> dict:
        """The options a farm job carries (the ones set)."""
        return {k: v for k, v in asdict(self).items() if v is not None and v != "" and v is not False}


#: option name → its ``tween train-rig`` flag.
FLAGS: dict[str, str] = flags_of(TrainRigOptions)


def command_args(options: dict) -> list[str]:
    """The ``tween train-rig`` flags of a job's options (unknown names are a ValueError)."""
    return job_args(options, FLAGS, "train-rig")


#: The typer command with every TrainRigOptions field as an option (``opts:
#: TrainRigOptions``), after the clip and ``--out``.
with_train_rig_options = with_options(TrainRigOptions, lead=2)
