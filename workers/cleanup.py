"""Undoing a fill job that failed or was cancelled: nothing of it stays on disk.

A job writes, in this order: take files in its work folder (``.tween-work/<job>``), its
versioned layers (the fill layer and the review layer, ``<shot>.tween.vNNN`` /
``<shot>.review.vNNN``, tagged with the job id), then per take its review media, rendered in
a hidden scratch folder of the review folder (``review/.tween-review-<job>.<pid>@<host>.*.tmp``)
and moved into place (``<shot>_vNNN_takeN.mp4``, frames, contact sheet, ``<shot>_vNNN.otio``).
:func:`undo` removes all of it; every step is idempotent, so the worker that fails, the main
process of a worker whose stage hit its hard time limit, and the client that cancelled may all
run it. :func:`clean_scratch` removes a dead run's scratch of one job (the worker that takes a
stage over runs it first).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

from render.scene import shot_label

SCRATCH_PREFIX = ".tween-review-"


def drop_work(work_dir: str | None, made_dirs=()) -> None:
    """Removes the job's work folder, and the output folders in ``made_dirs`` (the ones that
    did not exist when the job was submitted, deepest first) if nothing else is in them."""
    if work_dir:
        shutil.rmtree(work_dir, ignore_errors=True)
        try:
            os.rmdir(os.path.dirname(work_dir))  # .tween-work itself, once no other job uses it
        except OSError:
            pass
    for d in made_dirs or ():
        try:
            os.rmdir(d)
        except OSError:
            break


NOTE = "job.json"


def note_job(work_dir: str, shot: str, opts: dict, job: dict) -> None:
    """Writes ``job.json`` (the job id, shot and output folder) into the job's work folder,
    once: what the next run needs to undo a job whose embedded farm was killed."""
    path = os.path.join(work_dir, NOTE)
    if os.path.exists(path):
        return
    rec = {"id": job["id"], "shot": shot, "out_dir": opts.get("out_dir") or ""}
    tmp = f"{path}.{os.getpid()}.part"
    with open(tmp, "w") as f:
        json.dump(rec, f)
    os.replace(tmp, path)


def undo_dead(work_dir: str) -> tuple[dict, list[str]] | None:
    """Undoes the job whose work folder ``work_dir`` is (its writer is dead: the caller
    checked); returns its note and what was removed, or None without a note."""
    try:
        with open(os.path.join(work_dir, NOTE)) as f:
            rec = json.load(f)
        shot, job_id = str(rec["shot"]), str(rec["id"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return rec, undo(shot, {"out_dir": rec.get("out_dir") or None}, {"id": job_id, "work_dir": work_dir})


def review_dir(layer: dict) -> str:
    """The folder a job's review media go to: ``review/`` beside its review layer."""
    return os.path.join(os.path.dirname(layer.get("review") or layer["layer"]), "review")


def clean_scratch(folder: str | Path, job_id: str) -> list[str]:
    """Removes the render scratch folders of ``job_id`` in ``folder`` (whoever made them)."""
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for e in entries:
        if e.name.startswith(f"{SCRATCH_PREFIX}{job_id}."):
            shutil.rmtree(e.path, ignore_errors=True)
            removed.append(e.path)
    return removed


def version_media(review_layer: str, folder: str | Path) -> list[Path]:
    """The review media of one fill version in ``folder``: the files named after the review
    layer's label (``sh010_v003.otio``, ``sh010_v003_take1.mp4``, ``sh010_v003_take1.1001.png``…)."""
    label = shot_label(review_layer).replace(" ", "_")
    try:
        names = os.listdir(folder)
    except OSError:
        return []
    return [Path(folder) / n for n in names if n.startswith((f"{label}.", f"{label}_"))]


def undo(shot: str, opts: dict, job: dict) -> list[str]:
    """Removes everything job ``job`` wrote for ``shot``: review media and scratch, layers,
    work folder, and the output folders it made when they are empty. Returns what it removed.
    A render-only job (``job["kind"] == "review"``) removes only the media it made."""
    from pipeline.usd import write

    if job.get("kind") == "review":
        return undo_render(job)
    removed: list[str] = []
    out_dir = Path(opts.get("out_dir") or write.default_out_dir(shot))
    done = write.find_job(out_dir, write.shot_stem(shot), job["id"], shot) if out_dir.is_dir() else None
    if done:
        removed += _drop_media(review_dir(done), job["id"], done.get("review"))
        for key in ("review", "layer"):  # the layer last: it is how the job's files are found
            p = done.get(key)
            if p and os.path.isfile(p):
                os.unlink(p)
                removed.append(p)
    else:  # no layers: a scratch may still be there if the layers went first
        removed += clean_scratch(out_dir / "review", job["id"])
    drop_work(job.get("work_dir"), job.get("made_dirs", ()))
    return removed


def undo_render(job: dict) -> list[str]:
    """Removes what a render-only job made: its scratch, and the media of its version that were
    not there when it was submitted (``job["existing"]``). The fill version itself stays."""
    review = job["review"]
    return _drop_media(review_dir({"review": review}), job["id"], review, set(job.get("existing") or ()))


def _drop_media(folder: str, job_id: str, review: str | None, keep=frozenset()) -> list[str]:
    """Removes job ``job_id``'s render scratch in ``folder`` and the media there of the version
    whose review layer is ``review`` (but those named in ``keep``), then ``folder`` if that
    emptied it. Returns what it removed."""
    removed = clean_scratch(folder, job_id)
    for p in version_media(review, folder) if review else ():
        if p.name not in keep:
            p.unlink(missing_ok=True)
            removed.append(str(p))
    try:
        os.rmdir(folder)  # the review folder, if this job's media were all it held
    except OSError:
        pass
    return removed
