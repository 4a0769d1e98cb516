"""Building a library from a studio's takes (``tween library build``).

Every BVH and USD take under a folder goes the way a shot goes to the model (the fill's own
joint mapping and retargeting, :func:`pipeline.usd.take.studio_take`), resampled to the
model's 30 fps, then its match features, facing and foot contacts are computed and appended
to the library's arrays (:mod:`pipeline.library.store`). Memory follows one take. A take that
cannot be read is one line on stderr naming the file; the others go on. ``add=True`` appends
the takes the library does not hold yet (by resolved path) and keeps the rest as it is.
"""

from __future__ import annotations

import gzip
import shutil
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pipeline.atomic import locked
from pipeline.data.skeletons import bandai_mirror, bandai_skeleton
from pipeline.errors import TweenError, printable
from pipeline.library.match_features import contacts, frame_features
from pipeline.library.options import LOCK_WAIT_S
from pipeline.library.store import (
    ARRAYS,
    MANIFEST,
    LibraryError,
    Writer,
    empty_manifest,
    is_library,
    open_library,
    verify,
)
from pipeline.motion.bvh import gzipped, is_bvh
from pipeline.outputs import missing_folders, refuse_read_only, remove_created
from pipeline.progress import interval

FPS = 30.0


def take_arrays(motion) -> dict[str, np.ndarray]:
    """The per-frame arrays of one take on the model skeleton at the library's rate."""
    rot = np.asarray(motion.rotations, np.float32)
    root = np.asarray(motion.root_positions, np.float32)
    feats, turn = frame_features(rot, root, motion.skeleton)
    return {
        "rotations": rot,
        "roots": root,
        "features": feats,
        "sqnorm": (feats.astype(np.float64) ** 2).sum(1).astype(np.float32),
        "facing": turn.astype(np.float32),
        "contacts": contacts(rot, root, motion.skeleton),
    }


def mirrored(motion):
    """The take's left/right mirror image (the model skeleton's mirror, pipeline.motion.mirror)."""
    m = bandai_mirror()
    rot = m.rotations(np.asarray(motion.rotations, np.float64), motion.skeleton.parents)
    return replace(motion, rotations=rot.astype(np.float32), root_positions=m.root(motion.root_positions))


def _rig_of(path: Path) -> str:
    """What the take came from, for the manifest: a BVH's joint count, root and rate from its
    header (read up to MOTION, not the frames), or "USD"."""
    if not is_bvh(path):
        return "USD"
    joints, root, rate = 0, "", ""
    with (gzip.open if gzipped(path) else open)(path, "rt", encoding="utf-8", errors="replace") as f:
        for line in f:
            word = line.split()[:2]
            if word and word[0] in ("ROOT", "JOINT"):
                joints += 1
                root = root or (word[1] if len(word) > 1 else "")
            elif line.strip().startswith("Frame Time:"):
                rate = f", {1.0 / float(line.split(':')[1]):g} fps"
                break
    return f"BVH, {joints} joints from {root}{rate}"


def _skipped(line: str) -> None:
    print(f"tween: skipped take: {line}", file=sys.stderr)


#: The lock every build of a library holds from its first look at the folder to its
#: manifest (``pipeline.atomic.locked``): two builds adding at once each appended to the
#: arrays and each wrote its own manifest, which lost the other's takes and left arrays
#: longer than the manifest says. Removed when released; not counted as the folder's content.
LOCK = ".library.lock"


def _lock_timed_out(lock: Path, waited: float) -> LibraryError:
    """The line a build that waited ``waited`` seconds for ``lock`` gives up with: who holds
    it (``pipeline.usd.files.lock_holder``, as the fill's own locks say it)."""
    from pipeline.usd.files import lock_holder

    return LibraryError(
        f"{lock}: another build still holds this library's lock after {waited:g} s ({lock_holder(lock)}); "
        "run again once it is done, or wait longer with --lock-wait SECONDS"
    )


def _contents(out: Path) -> list[Path]:
    """What ``out`` holds, but a build's lock."""
    return [p for p in out.iterdir() if p.name != LOCK]


def _leftovers(out: Path) -> list[Path]:
    """What a first build killed before its manifest was written left in ``out`` (its array
    files, a manifest being written), when ``out`` holds nothing else; else []."""
    if not out.is_dir() or is_library(out):
        return []
    names = {f"{a}.bin" for a in ARRAYS}
    found = _contents(out)
    ours = [p for p in found if p.is_file() and (p.name in names or p.name.startswith(f".{MANIFEST}."))]
    return ours if ours and len(ours) == len(found) else []


def check_out(out: Path, add: bool) -> None:
    """Refuses an ``out`` that is not empty (without ``add``) or not a library (with it),
    counting what a killed first build left there (:func:`_leftovers`) as nothing. Also what
    `tween submit-library` checks before it sends the job. A read-only folder (by its mode
    bits, even for root) is refused as other commands refuse it."""
    refuse_read_only(out, "--out")
    if _leftovers(out):
        return
    if out.exists() and not add and (not out.is_dir() or _contents(out)):
        what = "a library" if is_library(out) else "not empty" if out.is_dir() else "a file, not a folder"
        raise LibraryError(f"{out}: {what}; use --add to append takes, or a new folder")
    if add and out.exists() and not is_library(out) and _contents(out):
        raise LibraryError(f"{out}: not a library (no library.json); --add appends to a library")
    if add and is_library(out):
        open_library(out)  # a damaged manifest is named before any take is read


def _remove_leftovers(out: Path) -> None:
    left = _leftovers(out)
    if left:
        print(f"tween: {out}: removing the {len(left)} file(s) a build that was stopped left (no library.json)",
              file=sys.stderr)  # fmt: skip
        for p in left:
            p.unlink()


def _start_manifest(out: Path, add: bool, licence: str | None, name: str | None) -> dict:
    """The manifest the takes are added to: the library's at ``out`` (with ``add``), else a
    new one."""
    skel = bandai_skeleton()
    if add and is_library(out):
        lib = open_library(out)
        verify(lib)  # as `tween library info` checks it: takes added to a damaged library were lost with it
        manifest = dict(lib.manifest)
        if licence and manifest.get("licence") and licence != manifest["licence"]:
            print(f"tween: {out}: new takes under licence {licence!r}; the library says {manifest['licence']!r}",
                  file=sys.stderr)  # fmt: skip
        return manifest
    return empty_manifest(name or out.resolve().name, licence, skel.names, FPS)


def _read_take(path: Path):
    """The take at ``path``: (its motion, its rig's name, its arrays); raises what a bad
    take raises."""
    from pipeline.usd.take import studio_take

    motion = studio_take(path)
    if len(motion) < 2:
        raise TweenError(f"{path}: fewer than two frames")
    return motion, _rig_of(path), take_arrays(motion)


def _add_takes(writer: Writer, bar, n: int, manifest: dict, licence, mirror: bool, on_progress):
    """Reads each take of ``bar`` (``n`` of them) into ``writer``; a take that cannot be read
    is skipped. Returns (how many were added, the failed ones, the failure lines not yet said)."""
    failed, added, held = [], 0, []
    for done, path in enumerate(bar):
        if on_progress is not None:
            on_progress(done, n, path.name)
        try:
            motion, rig, arrays = _read_take(path)
        except (TweenError, ValueError, IndexError, OSError, KeyError) as e:
            msg = printable(str(e).strip() or type(e).__name__)  # a name with a newline: one line
            line = msg if printable(path) in msg else f"{printable(path)}: {msg}"
            failed.append({"file": str(path), "why": msg})
            # Said once a take has been read: until then a folder of nothing readable is
            # refused in one line that names its first bad take.
            held.append(line) if not (added or manifest["takes"]) else _skipped(line)
            continue
        entry = {"name": path.name, "file": str(path.resolve()), "rig": rig}
        if licence:
            entry["licence"] = licence
        writer.add(entry, arrays)
        if mirror:  # the same motion with the other hand and foot leading
            writer.add(entry | {"name": f"{path.name} (mirrored)", "mirrored": True},
                       take_arrays(mirrored(motion)))  # fmt: skip
        added += 1
        for line in held:
            _skipped(line)
        held.clear()
    return added, failed, held


def build(folder, out, include: str | None = None, licence: str | None = None, name: str | None = None,
          add: bool = False, files=None, progress: bool = True, mirror: bool = False,
          on_progress=None, lock_wait: float = LOCK_WAIT_S) -> dict:  # fmt: skip
    """Reads the takes under ``folder`` (or the paths in ``files``) into the library ``out``;
    returns {"library", "added", "skipped", "failed", "frames", "hours", "hash"}. Without
    ``add`` an existing library at ``out`` is refused (build into a new folder, or add).
    ``on_progress(done, total, name)`` is called after each take (the farm's progress);
    ``lock_wait``: seconds to wait for another build of ``out`` (then a LibraryError)."""
    from pipeline.usd.take import take_files

    out = Path(out)
    check_out(out, add)  # before the takes are listed: a wrong --out is said at once
    paths = [Path(p) for p in files] if files is not None else take_files(folder, include)
    made = []  # the folders the lock made (``out`` and any above it)

    def make() -> None:
        # Noted before they are made: an interrupt just after the mkdir left them, empty.
        made.extend(p for p in missing_folders(out) if p not in made)
        out.mkdir(parents=True, exist_ok=True)

    def waiting() -> None:
        print(f"tween: {out}: another build is writing this library; waiting for it (at most {lock_wait:g} s)",
              file=sys.stderr)  # fmt: skip

    from pipeline.usd.files import mark_holder  # who holds it, as every writer's temps name it

    lock = out / LOCK
    try:
        with locked(lock, make=make, waiting=waiting, timeout=lock_wait,
                    timed_out=lambda: _lock_timed_out(lock, lock_wait)):  # fmt: skip
            mark_holder(lock)
            return _build_locked(folder if files is None else out, out, paths, licence, name, add, progress, mirror, on_progress,
                                 out in made)  # fmt: skip
    finally:
        # What it made and left empty goes: ``out`` where it stopped before a file was written
        # in it (a failed build removed its files), and the folders above it.
        remove_created(made)


def _build_locked(where, out: Path, paths: list[Path], licence, name, add: bool, progress: bool, mirror: bool,
                  on_progress, created: bool) -> dict:  # fmt: skip
    """:func:`build`'s work, holding the library's lock: what the folder holds is read again
    here, since another build may have written it while this one waited. ``created``: this
    build made ``out``; ``where``: what a build none of whose takes could be read names."""
    check_out(out, add)
    _remove_leftovers(out)
    manifest = _start_manifest(out, add, licence, name)
    have = {t["file"] for t in manifest["takes"]}
    todo = []
    for p in paths:  # each file once (a take linked twice is one take)
        if str(p.resolve()) not in have:
            have.add(str(p.resolve()))
            todo.append(p)
    # What this call makes goes again if it ends with nothing: the folder, or what it put in
    # an empty one the user gave.
    was_empty = not is_library(out) and not _contents(out)
    created = created and was_empty
    writer = bar = None
    try:  # from the first file made: an interrupt anywhere after it removes what was made
        writer = Writer(out, manifest)
        bar = tqdm(todo, desc=f"library {out.name}", unit="take", file=sys.stderr,
                   disable=not progress or None, mininterval=max(2.0, interval()), delay=1.0)  # fmt: skip
        added, failed, held = _add_takes(writer, bar, len(todo), manifest, licence, mirror, on_progress)
        if not manifest["takes"] and failed:
            raise LibraryError(f"{where}: no take could be read ({len(failed)} failed; the first: {held[0]})")
        writer.commit()
        if on_progress is not None:
            on_progress(len(todo), len(todo), "")
    except BaseException:
        if writer is not None:  # the arrays as they were (closing alone raised on a full disk)
            writer.discard()
        if created:
            shutil.rmtree(out, ignore_errors=True)
        elif was_empty:
            for p in _contents(out):
                shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
        raise
    finally:
        if writer is not None:
            writer.close()
        if bar is not None:
            bar.close()
    lib = open_library(out)
    return {"library": str(out), "added": added, "skipped": len(paths) - len(todo), "failed": failed,
            "frames": lib.frames, "hours": lib.manifest["hours"], "hash": lib.hash,
            "takes": len(lib.manifest["takes"])}  # fmt: skip
