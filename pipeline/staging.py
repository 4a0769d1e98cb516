"""A model folder is made beside its destination and moved into place only when complete.

Training and export write a new model into ``.<name>.partial`` next to ``--out`` and swap it
in at the end, so a killed, failed or refused run leaves the model a studio already fills
with exactly as it was; a killed training's hidden folder is where the same command resumes.
A destination that holds a finished model is replaced only with ``--force``.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from pipeline.errors import TweenError

#: The files that make a folder a finished model (generator ONNX models, per-rig models).
MODEL_FILES = ("model.json", "rig.json")


def finished_model(folder: str | Path) -> str | None:
    """The file that makes ``folder`` a finished model, or ``None``."""
    folder = Path(folder)
    return next((f for f in MODEL_FILES if (folder / f).is_file()), None)


def refuse_model(dest: str | Path, option: str = "--out", force_hint: str | None = "--force") -> None:
    """Raises TweenError when ``dest`` holds a finished model (or is not a folder)."""
    dest = Path(dest)
    if dest.exists() and not dest.is_dir():
        raise TweenError(f"{dest}: {option} names a file, not a model folder")
    marker = finished_model(dest)
    if marker:
        how = f"give {force_hint} to replace it (the old model stays until the new one is complete)"
        raise TweenError(
            f"{dest}: {option} holds a finished model ({marker}); "
            + (how if force_hint else "choose another folder")
        )


class StagedFolder:
    """Where a new model is written (``work``) and how it replaces ``dest`` (``commit``).

    Refuses at once (before anything is written) when ``dest`` holds a finished model and
    ``force`` is not given. ``work`` is ``dest`` itself when ``dest`` exists without a
    finished model (an earlier run's unfinished folder: nothing to protect, and resuming
    continues there), else the hidden ``.<name>.partial`` beside it, made on first use."""

    def __init__(self, dest: str | Path, force: bool = False, option: str = "--out"):
        self.dest = Path(dest)
        if not force:
            refuse_model(self.dest, option)
        elif self.dest.exists() and not self.dest.is_dir():
            raise TweenError(f"{self.dest}: {option} names a file, not a model folder")
        unfinished = self.dest.is_dir() and finished_model(self.dest) is None
        self.work = self.dest if unfinished else self.dest.parent / f".{self.dest.name}.partial"

    def make(self) -> Path:
        """``work``, created (with its parents)."""
        self.work.mkdir(parents=True, exist_ok=True)
        return self.work

    def commit(self) -> Path:
        """Moves ``work`` into place as ``dest``; the model it replaces is removed last."""
        if self.work == self.dest:
            return self.dest
        old = None
        if self.dest.exists():
            old = self.dest.parent / f".{self.dest.name}.old-{os.getpid()}"
            os.rename(self.dest, old)
        try:
            os.rename(self.work, self.dest)
        except OSError:
            if old is not None:  # put the previous model back before saying why
                os.rename(old, self.dest)
            raise
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        return self.dest

    def discard(self) -> None:
        """Removes ``work`` unless it is ``dest`` (a failed export: nothing half-made stays)."""
        if self.work != self.dest:
            shutil.rmtree(self.work, ignore_errors=True)
