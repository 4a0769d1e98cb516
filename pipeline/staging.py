"""A model folder is made beside its destination and moved into place only when complete.

Training and export write a new model into ``.<name>.partial`` next to ``--out`` and swap it
in at the end, so a killed, failed or refused run leaves the model a studio already fills
with exactly as it was; a killed training's hidden folder is where the same command resumes.
A destination that holds a finished model is replaced only with ``--force``, and then only
the model's own files are replaced: anything else a studio keeps there (notes, renders) stays.
A destination that exists is used only when it is empty or holds a finished model.
"""

from __future__ import annotations

import glob
import json
import os
import re
import shutil
import sys
from pathlib import Path

from pipeline.errors import TweenError
from pipeline.outputs import refuse_read_only

#: The files that make a folder a finished model (generator ONNX models, per-rig models).
MODEL_FILES = ("model.json", "rig.json")
#: What else a model folder's writers put there: its card and its training checkpoints.
MODEL_EXTRAS = ("MODEL_CARD.md", "checkpoints")
#: A per-rig model's level files, whether or not its rig.json still lists them.
LEVEL_FILE = re.compile(r"level_\d+\.onnx")


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


def model_entries(folder: Path, new: Path | None = None) -> set[str]:
    """The names in ``folder`` that belong to its model: its manifest, card, checkpoints and
    level files, the files its manifest lists, and every name the ``new`` model has."""
    owned = set(MODEL_FILES) | set(MODEL_EXTRAS)
    if new is not None and new.is_dir():
        owned |= {p.name for p in new.iterdir()}
    for manifest in MODEL_FILES:
        try:
            owned |= _listed(json.loads((folder / manifest).read_text()).get("files"))
        except (OSError, ValueError, AttributeError, RecursionError):
            pass  # no manifest, or not one we can read: its level files are still recognised
    return owned | {p.name for p in folder.iterdir() if LEVEL_FILE.fullmatch(p.name)}


def _listed(files) -> set[str]:
    """The top-level names of the file paths a manifest's ``files`` entry lists."""
    if isinstance(files, str):
        return {Path(files).parts[0]} if files and not Path(files).is_absolute() else set()
    values = files.values() if isinstance(files, dict) else files if isinstance(files, list) else ()
    return {name for v in values for name in _listed(v)}


def _beside(dest: str | Path, suffix: str) -> Path:
    """The hidden ``.<name><suffix>`` beside ``dest`` (``--out .`` too: beside the folder,
    never in it)."""
    full = Path(os.path.abspath(dest))
    return full.parent / f".{full.name}{suffix}"


def partial_folder(dest: str | Path) -> Path:
    """The hidden folder beside ``dest`` where its new model is made; what a killed training
    resumes from."""
    return _beside(dest, ".partial")


def _refuse_current_folder(dest: Path, option: str) -> None:
    """TweenError when the current folder is ``dest`` or lies inside it: replacing ``dest``
    renames it away, and the shell that ran the command would be left in the old folder."""
    try:
        here = Path.cwd().resolve()
    except OSError:  # the current folder was removed: it is not dest
        return
    if here == dest.resolve() or dest.resolve() in here.parents:
        raise TweenError(
            f"{dest}: {option} is the folder you are in (or holds it); replacing it would move "
            "it from under you: run from outside it"
        )


def _keep_others(old: Path, dest: Path, fresh: bool = True) -> list[str]:
    """Moves what is not the old model's from ``old`` into the new model's folder ``dest``
    (what the studio kept beside the model: notes, renders); returns the names that ``dest``
    holds already, left in ``old``. ``fresh``: ``dest`` holds the new model alone, so every
    name in it is the model's (not so once kept files have joined it)."""
    owned, taken = model_entries(old, dest if fresh else None), []
    for p in sorted(old.iterdir()):
        if p.name in owned:
            continue
        if os.path.lexists(dest / p.name):
            taken.append(p.name)
            continue
        try:
            os.rename(p, dest / p.name)
        except OSError as e:
            raise TweenError(
                f"{dest}: the new model is in place, but {p} could not be moved back beside it "
                f"({e.strerror}); move it yourself"
            ) from None
    return taken


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def recover(dest: str | Path) -> None:
    """Puts back what a run killed inside :meth:`StagedFolder.commit` left in a hidden
    ``.<name>.old-PID`` beside ``dest`` (its process gone): killed between moving the old
    model aside and the new one in, ``dest`` is missing and the old model goes back; killed
    after, the files the studio kept beside the old model join the new one and the rest goes.
    Says so on stderr; a swap whose process still runs is left to it."""
    full = Path(os.path.abspath(dest))
    olds = []
    for p in full.parent.glob(f".{glob.escape(full.name)}.old-*"):
        pid = p.name.rsplit("-", 1)[1]
        if pid.isdigit() and p.is_dir() and not p.is_symlink() and not _alive(int(pid)):
            olds.append(p)
    for old in sorted(olds, key=lambda p: p.stat().st_mtime, reverse=True):
        if not os.path.lexists(full):
            os.rename(old, full)
            print(
                f"tween: {dest}: put back the model a killed run had moved aside ({old.name})",
                file=sys.stderr,
            )
            continue
        taken = _keep_others(old, full, fresh=False)
        if taken:  # never removes a file of the studio's: it says where it is
            print(f"tween: {dest}: a killed run left {', '.join(taken)} in {old}, and {dest} has its own: "
                  "compare them and move what you keep", file=sys.stderr)  # fmt: skip
            continue
        shutil.rmtree(old, ignore_errors=True)
        print(f"tween: {dest}: finished what a killed run left aside ({old.name}): kept files moved back",
              file=sys.stderr)  # fmt: skip


class StagedFolder:
    """Where a new model is written (``work``) and how it replaces ``dest`` (``commit``).

    Refuses at once (before anything is written) when ``dest`` holds a finished model and
    ``force`` is not given, and when ``dest`` is a folder that holds other things than a
    model (the user's files are never mixed with a model's). ``work`` is the hidden
    ``.<name>.partial`` beside ``dest``, made on first use; an empty ``dest`` is replaced by
    it. ``what`` names the kind of model folder in refusals."""

    def __init__(self, dest: str | Path, force: bool = False, option: str = "--out", what: str = "model"):
        self.dest = Path(dest)
        recover(self.dest)  # what a run killed while it replaced this model left aside
        if not force:
            refuse_model(self.dest, option)
        elif self.dest.exists() and not self.dest.is_dir():
            raise TweenError(f"{self.dest}: {option} names a file, not a model folder")
        if self.dest.is_dir() and finished_model(self.dest) is None and _has_entries(self.dest, option):
            raise TweenError(
                f"{self.dest}: {option} is not empty and not a {what} folder; "
                "give a new or empty folder (nothing in it was changed)"
            )
        if self.dest.is_dir():  # commit renames it, empty or a model
            _refuse_current_folder(self.dest, option)
        self.work = partial_folder(self.dest)
        refuse_read_only(self.dest, option, self.work.parent)  # where the model is made and moved in
        refuse_read_only(self.dest, option)  # and what it replaces (a published model stays)

    def make(self) -> Path:
        """``work``, created (with its parents)."""
        self.work.mkdir(parents=True, exist_ok=True)
        return self.work

    def commit(self) -> Path:
        """Moves ``work`` into place as ``dest``. The model it replaces is removed last; the
        other files of its folder (:func:`model_entries` names the model's) move to the new one."""
        old = None
        if self.dest.exists():
            old = _beside(self.dest, f".old-{os.getpid()}")
            os.rename(self.dest, old)
        try:
            os.rename(self.work, self.dest)
        except OSError:
            if old is not None:  # put the previous model back before saying why
                os.rename(old, self.dest)
            raise
        if old is not None:
            _keep_others(old, self.dest)
            shutil.rmtree(old, ignore_errors=True)
        return self.dest

    def discard(self) -> None:
        """Removes ``work`` (a failed export: nothing half-made stays)."""
        shutil.rmtree(self.work, ignore_errors=True)


def _has_entries(folder: Path, option: str) -> bool:
    try:
        with os.scandir(folder) as entries:
            return next(entries, None) is not None
    except OSError as e:
        raise TweenError(f"{folder}: {option}: {e.strerror}") from None
