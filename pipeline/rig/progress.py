"""Progress of a per-rig training run as structured records.

``pipeline.rig.train.train(..., on_progress=f)`` calls ``f(Progress(...))`` at the start of
each group of levels and after every iteration. Who shows them decides how:

- ``tween train-rig`` turns them into a bar on stderr (:class:`ProgressBar`);
- the farm (``workers/rig_tasks.py``) runs the trainer in a subprocess that writes them as JSON
  lines to a pipe (``--progress-fd``, :class:`JsonLinesWriter`), reads them back
  (:class:`JsonLinesReader`) and puts them in the task's meta. Nobody reads a bar's text.

Neither torch nor tqdm is imported here until a bar is made.
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import IO

from tqdm import tqdm

from pipeline.progress import interval


@dataclass(frozen=True)
class Progress:
    """Where a training run stands.

    ``step``/``steps`` count iterations over the whole run (every group of levels), so
    ``step`` never goes down during a run and ends at ``steps``; ``stage_step``/``stage_steps``
    are the same within the group of levels being trained (``stage``, e.g. ``"levels 3-4/7"``;
    ``group_levels`` its levels, 1-based, of ``n_levels``).
    """

    stage: str
    step: int
    steps: int
    loss: dict[str, float]  # the last iteration's loss terms (d, adv, con, rec); {} before one
    elapsed_s: float  # training wall time so far, earlier (resumed) sessions included
    eta_s: float | None  # seconds left at this session's pace; None until there is a pace
    stage_step: int = 0
    stage_steps: int = 0
    group_levels: tuple[int, ...] = ()
    n_levels: int = 0

    @property
    def fraction(self) -> float:
        """Share of the run done, 0 to 1."""
        return min(1.0, self.step / self.steps) if self.steps > 0 else 1.0

    @property
    def done(self) -> bool:
        return self.step >= self.steps

    def to_dict(self) -> dict:
        """A JSON-ready dict (``asdict`` with the tuple as a list)."""
        d = asdict(self)
        d["group_levels"] = list(self.group_levels)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Progress:
        """The record back from :meth:`to_dict` (or from a task's meta: other keys are ignored)."""
        names = {f for f in cls.__dataclass_fields__}
        kw = {k: v for k, v in d.items() if k in names}
        kw["group_levels"] = tuple(kw.get("group_levels", ()))
        kw["loss"] = {str(k): float(v) for k, v in (kw.get("loss") or {}).items()}
        return cls(**kw)


ProgressCallback = Callable[[Progress], None]


def format_duration(s: float | None) -> str:
    if s is None or not math.isfinite(s):
        return "?"
    s = int(round(s))
    h, rem = divmod(s, 3600)
    m, sec = divmod(rem, 60)
    return f"{h}:{m:02d}:{sec:02d}" if h else f"{m:02d}:{sec:02d}"


class ProgressBar:
    """A tqdm bar per group of levels on ``file`` (stderr), fed with records; a context manager.

    Shows what the trainer's own bar showed before (``levels 3-4/7: 40%|████ | 12/30`` with the
    loss terms), plus the whole run's share and time left.
    """

    def __init__(self, file: IO | None = None, disable: bool = False):

        self.file = file if file is not None else sys.stderr
        self.disable = disable
        self._bar = None
        self._stage: str | None = None

    def __call__(self, p: Progress) -> None:

        if p.stage != self._stage:
            self.close()
            self._stage = p.stage
            self._bar = tqdm(
                total=p.stage_steps,
                initial=p.stage_step,
                desc=p.stage,
                file=self.file,
                disable=self.disable,
                dynamic_ncols=True,
                mininterval=interval(self.file),
            )
        bar = self._bar
        post = {k: f"{v:.3g}" for k, v in p.loss.items()}
        post["run"] = f"{100 * p.fraction:.0f}%"
        post["left"] = format_duration(p.eta_s)
        bar.set_postfix(post, refresh=False)
        bar.update(p.stage_step - bar.n)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
            self._stage = None

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class JsonLinesWriter:
    """Writes each record as one JSON line to ``stream`` (flushed); a context manager that
    closes the stream."""

    stream: IO[str]

    def __call__(self, p: Progress) -> None:
        self.stream.write(json.dumps(p.to_dict(), separators=(",", ":")) + "\n")
        self.stream.flush()

    def close(self) -> None:
        self.stream.close()

    def __enter__(self) -> JsonLinesWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class JsonLinesReader:
    """Records back from the bytes a :class:`JsonLinesWriter` wrote, fed in chunks as they come
    from a pipe (a record cut between two chunks waits for the rest)."""

    _buf: bytearray = field(default_factory=bytearray)

    def feed(self, chunk: bytes) -> list[Progress]:
        self._buf += chunk
        out = []
        while (i := self._buf.find(b"\n")) >= 0:
            line = bytes(self._buf[:i])
            del self._buf[: i + 1]
            if line.strip():
                out.append(Progress.from_dict(json.loads(line)))
        return out
