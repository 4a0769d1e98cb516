"""A take of any humanoid rig on the model skeleton, the way a shot reaches the model.

A USD file's first animated character (the same reading, joint mapping and retargeting as
a shot's), or a BVH file, converted to a USD take first so that it goes the same way. The
source of a motion DNA (``tween fill --dna``), of a studio's own clips for fine-tuning
(``tween train --data``) and of the held-out CMU windows of the bench.
"""

from __future__ import annotations

import fnmatch
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from pipeline.adapt.mapping import MappingError, load_override, map_joints
from pipeline.data.skeletons import bandai_skeleton
from pipeline.errors import ShotError
from pipeline.inputs import not_a_file
from pipeline.motion.bvh import is_bvh
from pipeline.motion.clip import Motion
from pipeline.usd.files import owner_tag, temp_full


def _usd_take(path: Path, fps: float, name: str, source: Path | None = None, override=None) -> Motion:
    """``source``: the file the user named, when ``path`` is its conversion (a BVH's);
    ``override``: a joint mapping file's roles (pipeline.adapt.mapping.load_override)."""
    from pipeline.adapt.retarget import Retarget
    from pipeline.usd.read import anim_values, read_shot, to_skeleton_order

    shot = read_shot(path)
    c = shot.characters[0]
    try:
        rt = Retarget(
            c, map_joints(c.joints, c.parents, override, c.other_joints), shot.up_axis, shot.meters_per_unit
        )
    except MappingError as e:
        # Libraries and DNA read takes by their names alone; a corpus source may give a mapping.
        how = "with the source's mapping" if override else "by their joint names alone"
        raise ShotError(
            source or path,
            f"{e.reason} (takes are read {how})",
            None if source else c.skel_path,
        ) from None
    times = np.arange(shot.start, shot.end + 1e-6, shot.tcps / fps)
    if len(times) < 2:
        raise ShotError(source or path, "the take has fewer than two frames")
    rot, tr = to_skeleton_order(c, *anim_values(shot.stage, c, times)[:2])
    q, root = rt.to_model(rot, tr)
    return Motion(bandai_skeleton(), q, root, fps, name).continuous()


def model_take(path: str | Path, fps: float = 30.0, mapping: str | Path | None = None) -> Motion:
    """The take in ``path`` (.usd/.usda/.usdc, or .bvh/.bvh.gz) on the model skeleton;
    ``mapping``: a joint mapping file for its rig (as ``tween fill --mapping``)."""
    path = Path(path)
    override = load_override(mapping)
    if why := not_a_file(path, "take file"):
        raise ShotError(path, why)
    if is_bvh(path):
        from pipeline.motion.bvh import read_bvh
        from pipeline.usd.convert import write_shot

        try:
            m = read_bvh(path)
        except (ValueError, IndexError, OSError) as e:
            raise ShotError(path, f"cannot read the BVH: {e}") from None
        # Named as the fill's take folders, so that a killed run's goes when a fill cleans the
        # system temp folder (pipeline.usd.files.clean_dead_temps).
        with (
            temp_full(f"converting the take {path}"),
            tempfile.TemporaryDirectory(prefix=f"tween-take.{owner_tag()}.", suffix=".tmp") as tmp,
        ):
            return _usd_take(
                write_shot(m, Path(tmp) / "take.usda", start=0, fps=fps), fps, m.name, path, override
            )
    return _usd_take(path, fps, path.name, override=override)


TAKE_SUFFIXES = (".bvh", ".bvh.gz", ".usd", ".usda", ".usdc", ".usdz")


def take_paths(folder: Path, onerror=None):
    """Every path under ``folder`` named like a take, of whatever kind (a file, a pipe, a link
    that leads nowhere), through linked folders too (each real folder once, so a link to a
    folder above is no loop); a folder named like a take is walked into. ``onerror``:
    ``os.walk``'s, for a folder that cannot be listed (passed over without it)."""
    seen = set()
    for top, dirs, names in os.walk(folder, onerror=onerror, followlinks=True):
        real = os.path.realpath(top)
        if real in seen:
            dirs[:] = []
            continue
        seen.add(real)
        for n in names:
            if n.lower().endswith(TAKE_SUFFIXES):
                yield Path(top) / n


def include_globs(include: str | None) -> list[str]:
    """``include`` (comma-separated file-name globs, e.g. ``"001_*,002_*"``) as its globs."""
    return [p.strip() for p in (include or "").split(",") if p.strip()]


def included(name: str, globs: list[str]) -> bool:
    """Whether the file ``name`` matches one of ``globs`` (every name, with none)."""
    return not globs or any(fnmatch.fnmatch(name, q) for q in globs)


def take_files(folder: str | Path, include: str | None = None) -> list[Path]:
    """The BVH and USD takes under ``folder`` (recursively), sorted; with ``include``
    (comma-separated file-name globs, e.g. ``"001_*,002_*"``) only the names that match one.
    A link to nothing named like a take is reported on stderr."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ShotError(
            folder, "is a file, not a folder of takes" if folder.exists() else "no such folder of takes"
        )
    folder = folder.resolve()  # one cache for a folder, however it is named
    pats = include_globs(include)
    files = []
    for p in take_paths(folder):
        if p.is_file():
            files.append(p)
        elif p.is_symlink():
            print(f"tween: skipped take: {p}: a link to nothing ({os.readlink(p)})", file=sys.stderr)
    files = sorted(p for p in files if included(p.name, pats))
    if not files:
        what = f"matching {include!r}" if pats else "(" + ", ".join(TAKE_SUFFIXES) + ")"
        raise ShotError(folder, f"no BVH or USD takes {what} in this folder")
    return files


def studio_take(path: Path) -> Motion:
    """A take as the model trains on it: 30 fps on the model skeleton, quaternions continuous.
    BVH already on the model skeleton is read as the protocol reads it (exactly); any other
    rig goes through :func:`model_take`, the fill's own mapping and retargeting."""
    if is_bvh(path):
        from pipeline.motion.bvh import read_bvh

        try:
            m = read_bvh(path)
        except (ValueError, IndexError, OSError) as e:
            raise ShotError(path, f"cannot read the BVH: {e}") from None
        if m.skeleton.names == bandai_skeleton().names and abs(m.fps - 30.0) < 1e-3:
            return m.continuous()
    return model_take(path, 30.0)


def load_takes(folder: str | Path, include: str | None = None, limit: int | None = None):
    """A studio's own takes (``take_files``) on the model skeleton, as a cached ClipSet: what
    ``tween train --data FOLDER`` trains on; ``limit``: the first N of them (``--limit-clips``)."""
    from pipeline.data.cache import load_files

    files = take_files(folder, include)
    return load_files(files[:limit] if limit else files, "takes", read=studio_take)
