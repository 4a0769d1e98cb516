"""The library folder: a manifest and flat arrays, memory-mapped.

``library.json`` names the takes (file, frames, first frame, rig, licence as the studio states
it), the skeleton and frame rate every frame is on (the model's), the arrays' shapes, and the
library's **hash**: a chain over its takes' contents (``tween library build --add`` extends the
chain), recorded in every fill that uses it so that fill can be reproduced.

Each array is a raw little-endian file (``ARRAYS``) read with ``np.memmap``: a worker maps the
files, and every process of a host shares one copy in the page cache whatever its
concurrency. Takes are appended to the files; the manifest, written last and atomically, says
how many frames are valid, so an interrupted ``--add`` leaves the library as it was: a failed
one (a full disk, Ctrl-C) cuts the files back to their sizes before it, and the bytes a killed
one left past the manifest's frames are cut off by the next ``--add``.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from pipeline import jsonfile
from pipeline.atomic import naming, write_bytes
from pipeline.errors import TweenError
from pipeline.inputs import read_small_text

MANIFEST = "library.json"
#: The most bytes library.json may hold (a take is a few hundred bytes of it): a pipe or a
#: device in its place blocked or ate memory (read_small_text).
MANIFEST_LIMIT = 64 << 20
KIND = "tween-library"
VERSION = 1
#: name → (dtype, shape of one frame's entry).
ARRAYS: dict[str, tuple[str, tuple[int, ...]]] = {
    "rotations": ("<f4", (21, 4)),  # local joint rotations, xyzw, on the model skeleton
    "roots": ("<f4", (3,)),  # root positions (cm, Y up)
    "features": ("<f4", (64,)),  # pipeline.library.match_features.frame_features
    "sqnorm": ("<f4", ()),  # |features|² (the search's dot-product form)
    "facing": ("<f4", (4,)),  # yaw quaternion turning the pose to face +X
    "contacts": ("u1", (2,)),  # left / right foot on the ground
    # index of the last frame of this frame's take: written for readers of version 1,
    # checked for its size on opening and against the manifest by verify (`library info`),
    # but read from the manifest here (Library.take_end)
    "take_end": ("<i4", ()),
}


class LibraryError(TweenError):
    """A library folder that cannot be used; one line naming it."""


#: How a line about a damaged array file ends.
REBUILD = "(the library is damaged; build it again)"
#: What a library array that is not finite numbers says.
DAMAGED = f"not finite numbers {REBUILD}"
#: How far from length 1 a stored rotation or facing may be (float32 rounding: ~1e-7).
UNIT_TOL = 1e-3
#: Frames :func:`verify` reads at once (0.6 kB a frame of array files: 10 hours, 0.7 GB).
VERIFY_BLOCK = 65536


@dataclass
class Library:
    """An open library: ``manifest`` and the arrays as read-only memory maps (attributes named
    as in :data:`ARRAYS`)."""

    folder: Path
    manifest: dict

    @property
    def frames(self) -> int:
        return int(self.manifest["frames"])

    @property
    def hash(self) -> str:
        return str(self.manifest["hash"])

    @property
    def name(self) -> str:
        return str(self.manifest.get("name") or self.folder.name)

    @property
    def fps(self) -> float:
        return float(self.manifest["fps"])

    def array(self, name: str) -> np.ndarray:
        dtype, shape = ARRAYS[name]
        if self.frames == 0:
            return np.zeros((0, *shape), dtype)
        return np.memmap(self.folder / f"{name}.bin", dtype=dtype, mode="r", shape=(self.frames, *shape))

    @cached_property
    def rotations(self) -> np.ndarray:
        return self.array("rotations")

    @cached_property
    def roots(self) -> np.ndarray:
        return self.array("roots")

    @cached_property
    def features(self) -> np.ndarray:
        return self.array("features")

    @cached_property
    def sqnorm(self) -> np.ndarray:
        return self.array("sqnorm")

    @cached_property
    def facing(self) -> np.ndarray:
        return self.array("facing")

    @cached_property
    def contacts(self) -> np.ndarray:
        return self.array("contacts")

    @cached_property
    def take_end(self) -> np.ndarray:
        """(F,) int32: index of the last frame of each frame's take, from the manifest's takes
        (checked to tile the frames on opening), not take_end.bin: a damaged one would let
        windows run across takes."""
        takes = self.manifest["takes"]
        ends = np.array([t["start"] + t["frames"] - 1 for t in takes], np.int32)
        return np.repeat(ends, [int(t["frames"]) for t in takes])

    @cached_property
    def take_start(self) -> np.ndarray:
        """(F,) int32: index of the first frame of each frame's take."""
        takes = self.manifest["takes"]
        starts = np.array([t["start"] for t in takes], np.int32)
        return np.repeat(starts, [int(t["frames"]) for t in takes])

    @cached_property
    def frames_left(self) -> np.ndarray:
        """(F,) int32: frames of its take after each frame."""
        return (self.take_end - np.arange(self.frames, dtype=np.int32)).astype(np.int32)

    @cached_property
    def frames_before(self) -> np.ndarray:
        """(F,) int32: frames of its take before each frame."""
        return (np.arange(self.frames, dtype=np.int32) - self.take_start).astype(np.int32)

    def describe(self) -> str:
        m = self.manifest
        return (
            f"{self.folder}: {len(m['takes'])} take(s), {self.frames} frames at {self.fps:g} fps "
            f"({m['hours']:.2f} h), licence {m.get('licence') or 'not stated'}, hash {self.hash}"
        )


def is_library(folder: str | Path) -> bool:
    return (Path(folder) / MANIFEST).is_file()


def open_library(folder: str | Path) -> Library:
    """The library in ``folder``; LibraryError (one line naming the folder) when it is none,
    or its files do not hold the frames its manifest says."""
    folder = Path(folder)
    path = folder / MANIFEST
    if not folder.is_dir():
        what = "a file, not a library folder" if folder.exists() else "no such library folder"
        raise LibraryError(f"{folder}: {what} (make one with `tween library build`)")
    try:
        manifest = jsonfile.loads(read_small_text(path, MANIFEST_LIMIT, MANIFEST))
    except FileNotFoundError:
        raise LibraryError(
            f"{folder}: not a library (no {MANIFEST}; make one with `tween library build`)"
        ) from None
    except (OSError, UnicodeDecodeError, ValueError) as e:
        raise LibraryError(f"{path}: cannot read: {e}") from None
    if not isinstance(manifest, dict) or manifest.get("kind") != KIND:
        raise LibraryError(f"{path}: not a usd-tween library manifest")
    if manifest.get("version") != VERSION:
        raise LibraryError(f"{path}: library version {manifest.get('version')!r}, this tween reads {VERSION}")
    frames = manifest.get("frames")
    if not isinstance(frames, int) or frames < 0 or not isinstance(manifest.get("takes"), list):
        raise LibraryError(f"{path}: manifest without a frame count or takes")
    _check_manifest(path, manifest)
    for name, (dtype, shape) in ARRAYS.items():
        need = frames * int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
        f = folder / f"{name}.bin"
        try:
            have = f.stat().st_size
        except OSError:
            raise LibraryError(f"{f}: missing (the library is incomplete; build it again)") from None
        if have < need:
            raise LibraryError(f"{f}: {have} bytes, the manifest's {frames} frames need {need}")
    return Library(folder, manifest)


def setting_library(value: str, named: str) -> str:
    """The library a setting names (``value``: a folder, relative to the working folder), as
    its absolute folder, opened: one that is no library is a LibraryError naming the setting
    as ``named`` (``TWEEN_LIBRARY=…``), not a folder the user never typed."""
    folder = os.path.abspath(os.path.expanduser(value))
    try:
        open_library(folder)
    except LibraryError as e:
        raise LibraryError(f"{named}: {str(e).removeprefix(f'{folder}: ')}") from None
    return folder


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _check_manifest(path: Path, m: dict) -> None:
    """LibraryError naming ``path`` unless the manifest's values are of the kinds the search
    and the fill read (a hand-edited or damaged one would fail inside them, or fill at a
    frame rate of NaN), and its takes tile its frames."""

    def bad(what: str):
        raise LibraryError(f"{path}: {what} (the manifest is damaged; build the library again)")

    fps = m.get("fps")
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not 1 <= fps < 1e4:
        bad(f"'fps' is {fps!r}, not a frame rate")
    if not isinstance(m.get("hash"), str) or not m["hash"]:
        bad(f"'hash' is {m.get('hash')!r}, not a string")
    hours = m.get("hours")
    if isinstance(hours, bool) or not isinstance(hours, (int, float)) or not 0 <= hours < 1e6:
        bad(f"'hours' is {hours!r}, not a number of hours")
    for key in ("name", "licence"):
        if m.get(key) is not None and not isinstance(m[key], str):
            bad(f"'{key}' is {m[key]!r}, not a string")
    skeleton = m.get("skeleton", [])
    if not isinstance(skeleton, list) or not all(isinstance(n, str) for n in skeleton):
        bad("'skeleton' is not a list of joint names")
    start = 0
    for i, t in enumerate(m["takes"]):
        if not isinstance(t, dict):
            bad(f"take {i} is not an object")
        for key in ("name", "file"):
            if not isinstance(t.get(key), str) or not t[key]:
                bad(f"take {i} has no {key!r}")
        if not _is_int(t.get("start")) or not _is_int(t.get("frames")) or t["frames"] < 1:
            bad(f"take {i} ({t['name']}) has no whole 'start' and 'frames'")
        if t["start"] != start:
            bad(f"take {i} ({t['name']}) starts at frame {t['start']}, after {start} frames of takes")
        start += t["frames"]
    if start != m["frames"]:
        bad(f"its takes hold {start} frames, its 'frames' says {m['frames']}")


def damage(name: str, values) -> str | None:
    """What is wrong with ``values`` (any frames) of the array ``name`` that they alone show,
    as the end of a line naming its file; None when nothing is. The fill asks it of the
    frames it reads, :func:`verify` of every frame."""
    a = np.asarray(values)
    if name == "contacts":
        return None if (a <= 1).all() else f"foot contacts other than 0 and 1 {REBUILD}"
    if a.dtype.kind != "f":
        return None
    if not np.isfinite(a).all():
        return DAMAGED
    if name in ("rotations", "facing"):
        length = np.linalg.norm(a.astype(np.float64), axis=-1)
        if not (np.abs(length - 1.0) <= UNIT_TOL).all():
            return f"quaternions that are not of length 1 {REBUILD}"
    return None


def sqnorm_damage(features, sqnorm) -> str | None:
    """None when ``sqnorm`` holds the squared lengths of the same frames' ``features`` (the
    search's dot-product form needs both): either file overwritten with finite numbers
    (another library's, random) disagrees; the line names both files."""
    f = np.asarray(features, np.float64)
    want = (f * f).sum(-1)
    if (np.abs(want - np.asarray(sqnorm, np.float64)) <= 1e-5 * want + 1e-3).all():
        return None
    return f"squared lengths that are not the features' {REBUILD}"


def verify(lib: Library) -> None:
    """LibraryError naming the first array file, and its block of frames, that holds what no
    library holds (:func:`damage`, :func:`sqnorm_damage`, take ends other than the
    manifest's). Reads every frame once, a block at a time: for `tween library info`, which a
    TD runs to check a library; the fill checks only the frames it reads."""
    arrays = {name: lib.array(name) for name in ARRAYS}
    for s in range(0, lib.frames, VERIFY_BLOCK):
        b = slice(s, s + VERIFY_BLOCK)
        for name, a in arrays.items():
            why = damage(name, a[b])
            if why is None and name == "sqnorm":
                why = sqnorm_damage(arrays["features"][b], a[b])
            if why is None and name == "take_end" and not np.array_equal(a[b], lib.take_end[b]):
                why = f"take ends that are not the manifest's {REBUILD}"
            if why:
                where = lib.folder / f"{name}.bin"
                where = f"{lib.folder / 'features.bin'} or sqnorm.bin" if name == "sqnorm" else where
                last = min(s + VERIFY_BLOCK, lib.frames) - 1
                raise LibraryError(f"{where}, frames {s}-{last}: {why}")


#: The frame rate a fill works at, which a library's takes must be at (pipeline.library.infer).
FILL_FPS = 30.0


def check_fillable(lib: Library) -> None:
    """LibraryError naming the manifest unless a fill can use ``lib``: its ``skeleton`` the
    model skeleton's joint names, in order, and its frame rate the fill's; what the fill
    (pipeline.library.infer) refuses, so that `tween library info` passes no library a fill
    refuses (a manifest that lost a joint name passed it)."""
    from pipeline.data.skeletons import bandai_skeleton

    path = lib.folder / MANIFEST
    names = tuple(bandai_skeleton().names)
    given = tuple(lib.manifest.get("skeleton", ()))
    if given != names:
        lost = [n for n in names if n not in given]
        odd = [n for n in given if n not in names]
        why = (
            f"joint {lost[0]!r} and {len(lost) - 1} more missing" if len(lost) > 1
            else f"joint {lost[0]!r} missing" if lost
            else f"joint {odd[0]!r} is not the model's" if odd
            else f"{len(given)} names for the model's {len(names)} joints, or in another order"
        )  # fmt: skip
        raise LibraryError(f"{path}: its takes are on another skeleton than the model's ({why}) {REBUILD}")
    if abs(lib.fps - FILL_FPS) > 1e-6:
        raise LibraryError(f"{path}: {lib.fps:g} fps, the fill works at {FILL_FPS:g} {REBUILD}")


def empty_manifest(name: str, licence: str | None, skeleton_names, fps: float) -> dict:
    return {
        "kind": KIND,
        "version": VERSION,
        "name": name,
        "licence": licence,
        "skeleton": list(skeleton_names),
        "fps": float(fps),
        "frames": 0,
        "hours": 0.0,
        "hash": hashlib.sha256(b"tween-library").hexdigest()[:16],
        "takes": [],
    }


class Writer:
    """Appends takes to a library folder; :meth:`commit` writes the manifest (atomically),
    :meth:`discard` cuts the arrays back to what the manifest holds. An OSError names its file
    (a full disk's names none)."""

    def __init__(self, folder: Path, manifest: dict):
        self.folder, self.manifest = folder, manifest
        folder.mkdir(parents=True, exist_ok=True)
        frames = int(manifest["frames"])
        self.files, self.sizes, self.committed = {}, {}, False
        for name, (dtype, shape) in ARRAYS.items():
            f = folder / f"{name}.bin"
            self.sizes[name] = frames * int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
            with naming(f):
                f.touch()
                with open(f, "r+b") as h:  # drop what an interrupted add left past the manifest
                    h.truncate(self.sizes[name])
                self.files[name] = open(f, "ab")

    def add(self, take: dict, arrays: dict[str, np.ndarray]) -> None:
        """One take: its manifest entry and its per-frame arrays (``take_end`` is made here)."""
        n = len(arrays["rotations"])
        start = int(self.manifest["frames"])
        arrays = dict(arrays, take_end=np.full(n, start + n - 1, np.int32))
        digest = hashlib.sha256()
        for name, (dtype, shape) in ARRAYS.items():
            a = np.ascontiguousarray(arrays[name], dtype=dtype)
            if a.shape != (n, *shape):
                raise ValueError(f"{name}: shape {a.shape}, expected {(n, *shape)}")
            if name != "take_end":
                digest.update(a.tobytes())
            with naming(self.folder / f"{name}.bin"):
                self.files[name].write(a.tobytes())
        chain = hashlib.sha256((self.manifest["hash"] + digest.hexdigest()).encode())
        self.manifest["hash"] = chain.hexdigest()[:16]
        self.manifest["takes"].append(dict(take, start=start, frames=n))
        self.manifest["frames"] = start + n
        self.manifest["hours"] = round(self.manifest["frames"] / self.manifest["fps"] / 3600.0, 6)

    def commit(self) -> None:
        for name, h in self.files.items():
            with naming(self.folder / f"{name}.bin"):
                h.flush()
                os.fsync(h.fileno())
        # Written whole or not at all, once the arrays it describes are on disk.
        write_bytes(self.folder / MANIFEST, json.dumps(self.manifest, indent=1).encode("utf-8"))
        self.committed = True  # the manifest holds the new frames: nothing is cut back now

    def close(self) -> None:
        for h in self.files.values():
            h.close()

    def discard(self) -> None:
        """After a failed add: the files closed, what could not be written dropped, and each
        cut back to the frames the manifest on disk holds, so the library is byte for byte as
        it was (a full disk had left the takes' bytes past its frames). After :meth:`commit`
        (an interrupt that came later) the arrays are the manifest's, and stay."""
        for h in self.files.values():
            try:
                h.close()
            except OSError:  # the buffered bytes it could not write (a full disk): dropped
                pass
        for name, size in self.sizes.items() if not self.committed else ():
            try:
                os.truncate(self.folder / f"{name}.bin", size)
            except OSError:  # (a file removed meanwhile): the next --add cuts it
                pass
