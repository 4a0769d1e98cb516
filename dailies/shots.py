"""The shots under the review roots: every folder's fill layers ``<stem>.tween.vNNN``, grouped
by shot, with the latest version's decision. Reads layer metadata only, cached by file
stamp, so listing many shots stays cheap. A listing reads each folder once, however many
shots share it (a sequence filled into one ``--out-dir``)."""

from __future__ import annotations

import glob
import os
import re
import stat
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from pipeline.usd.dailies import fill_decision
from pipeline.usd.files import review_path
from pipeline.usd.write import missing_fill, missing_latest

FILL = re.compile(r"^(?P<stem>[^.]+)\.tween\.v(?P<n>\d+)\.usd[ac]?$")
#: Folders never holding a shot's fills: the farm's work folders, review media.
SKIP_DIRS = ("review",)


@dataclass(frozen=True)
class Shot:
    """One shot's fills: ``key`` names it in URLs (root index, folder under the root, stem)."""

    key: str
    root: Path
    folder: Path
    stem: str
    versions: tuple[tuple[int, Path], ...]  # ascending

    @property
    def latest(self) -> tuple[int, Path]:
        return self.versions[-1]


_cache: dict[tuple, object] = {}
_cache_lock = threading.Lock()


def cached(path: Path, fn):
    """``fn(path)``, remembered while the file's size and modification time stay the same
    (layers are never rewritten in place, so a stamp names one content); None for a file
    not there or not a regular one (a pipe named like a layer would hold the request)."""
    try:
        st = path.stat()
    except OSError:
        return None
    if not stat.S_ISREG(st.st_mode):
        return None
    key = (fn.__qualname__, str(path), st.st_mtime_ns, st.st_size)
    with _cache_lock:
        if key in _cache:
            return _cache[key]
    value = fn(path)
    with _cache_lock:
        if len(_cache) > 20000:  # a long-running server: old stamps go
            _cache.clear()
        _cache[key] = value
    return value


def layer_info(path: Path) -> dict | None:
    """The layer's ``customLayerData["tween"]`` and sublayers (metadata only); None when
    unreadable."""
    from pxr import Sdf, Tf

    try:
        layer = Sdf.Layer.OpenAsAnonymous(str(path), True)
    except Tf.ErrorException:
        return None
    if layer is None:
        return None
    info = dict(layer.customLayerData.get("tween", {}))
    info["_sublayers"] = list(layer.subLayerPaths)
    return info


#: Seconds a walk of the roots is reused: many viewers on a large show tree walk it once.
SCAN_AGE = 5.0
_scans: dict[tuple, tuple[float, list]] = {}
_scan_lock = threading.Lock()


def scan(roots: list[Path], max_age: float | None = None) -> list[Shot]:
    """Every shot with a fill under ``roots``, as walked at most ``max_age`` (default
    ``SCAN_AGE``) seconds ago."""
    max_age = SCAN_AGE if max_age is None else max_age
    key = tuple(map(str, roots))
    with _scan_lock:  # one walk at a time: the others wait for its result
        t, found = _scans.get(key, (0.0, []))
        if time.monotonic() - t > max_age:
            found = _walk(roots)
            _scans[key] = (time.monotonic(), found)
        return found


def forget() -> None:
    """Drops the remembered walks (after a decision, so the list shows it at once)."""
    with _scan_lock:
        _scans.clear()


def _walk(roots: list[Path]) -> list[Shot]:
    """Every shot with a fill under ``roots`` (hidden folders and ``review`` skipped)."""
    found: dict[tuple[int, Path, str], dict[int, Path]] = {}
    for i, root in enumerate(roots):
        for folder, dirs, files in os.walk(root):
            dirs[:] = sorted(d for d in dirs if not d.startswith(".") and d not in SKIP_DIRS)
            for name in files:
                m = FILL.match(name)
                # Regular files only: a pipe named like a layer blocked every request that read it.
                if m and os.path.isfile(os.path.join(folder, name)):
                    found.setdefault((i, Path(folder), m["stem"]), {})[int(m["n"])] = Path(folder) / name
    shots = []
    for (i, folder, stem), versions in found.items():
        rel = folder.relative_to(roots[i]).as_posix()
        key = f"{i}/{stem}" if rel == "." else f"{i}/{rel}/{stem}"
        shots.append(Shot(key, roots[i], folder, stem, tuple(sorted(versions.items()))))
    return shots


def find(roots: list[Path], key: str) -> Shot | None:
    """The shot named ``key`` (as :func:`scan` names it), or None: only shots found under the
    roots are ever answered, so a key cannot point anywhere else."""
    head, _, rest = key.partition("/")
    if not head.isdigit() or int(head) >= len(roots) or not rest:
        return None
    root = roots[int(head)]
    folder, _, stem = rest.rpartition("/")
    if not stem or ".." in rest.split("/") or stem.startswith("."):
        return None
    path = root / folder if folder else root
    try:  # a key too long for a path (ENAMETOOLONG) names no shot either
        real = Path(os.path.realpath(path))
        # A linked folder leading out of the roots is not a shot of theirs (the scan never follows one).
        if not path.is_dir() or not any(real.is_relative_to(os.path.realpath(r)) for r in roots):
            return None
        versions = {}
        for p in path.glob(f"{glob.escape(stem)}.tween.v*.usd*"):
            m = FILL.match(p.name)
            if m and m["stem"] == stem and p.is_file():
                versions[int(m["n"])] = p
    except OSError:
        return None
    return Shot(key, root, path, stem, tuple(sorted(versions.items()))) if versions else None


def shot_file(shot: Shot) -> Path | None:
    """The animator's shot of the latest fill: the review layer's last sublayer (the shot
    under the fill), else the shot the fill recorded."""
    info = cached(shot.latest[1], layer_info) or {}
    review = shot.folder / str(info.get("review", ""))
    if info.get("review") and review.is_file():
        subs = (cached(review, layer_info) or {}).get("_sublayers", [])
        for sub in reversed(subs):
            if not FILL.match(Path(sub).name):
                p = Path(sub) if os.path.isabs(sub) else review.parent / sub
                return Path(os.path.normpath(p))
    recorded = info.get("shot")
    if recorded and os.path.isabs(recorded) and Path(recorded).is_file():
        return Path(recorded)
    return None


def folder_names(folder: Path) -> dict[str, list[str]]:
    """The names in ``folder`` (one listing), by the part before their first dot: a shot's
    stem has no dot, so every layer of the shot ``stem`` is under ``stem``. Empty when the
    folder cannot be listed."""
    try:
        names = os.listdir(folder)
    except OSError:
        return {}
    by_stem: dict[str, list[str]] = {}
    for name in names:
        by_stem.setdefault(name.partition(".")[0], []).append(name)
    return by_stem


def _read(path: Path) -> dict | None:
    """:func:`layer_info` as ``fill_decision`` reads a layer: cached; None when unreadable or
    not a regular file."""
    return cached(path, layer_info)


def _decision(shot: Shot, names: dict[str, list[str]]) -> dict | None:
    """``pipeline.usd.dailies.fill_decision`` of the shot's latest fill (less its ``layer``),
    from the folder's ``names`` rather than a listing of the folder per shot; it also sees
    an approval written since the walk (up to ``SCAN_AGE`` old)."""
    d = fill_decision(shot.latest[1], names.get(shot.stem, []), _read)
    if d:
        del d["layer"]
    return d


#: The status of a shot whose latest fill layer was deleted by hand, its review layer left.
MISSING = "latest fill missing"


def _row(shot: Shot, n: int, layer: Path, names: dict[str, list[str]], **fields) -> dict:
    """A row of the list: the shot, version ``n`` (its time: ``layer``'s), whether it is
    published, and ``fields`` (status, decision, model, takes, created, ...)."""
    publish = f"{shot.stem}.publish.v{n:03d}.usd"  # any such name, as a glob of ``publish*``
    try:
        mtime = layer.stat().st_mtime
    except OSError:
        mtime = 0.0
    row = {
        "key": shot.key,
        "stem": shot.stem,
        "folder": str(shot.folder),
        "version": n,
        "versions": len(shot.versions),
    }
    for k, v in fields.items():  # "published" after "decision": the API's order of fields
        row[k] = v
        if k == "decision":
            row["published"] = any(name.startswith(publish) for name in names.get(shot.stem, []))
    return row | {"mtime": mtime}


def summary(shot: Shot, names: dict[str, list[str]] | None = None) -> dict:
    """What the list shows of a shot: its latest version, status, model, time. ``names``:
    :func:`folder_names` of its folder (listed here when not given). A shot whose latest fill
    was deleted by hand (its review layer left) is shown as that (:data:`MISSING`, the layer
    named in ``missing``), not by the fill before it, which `tween review`, approve and
    publish refuse to take for the latest too."""
    n, path = shot.latest
    names = folder_names(shot.folder) if names is None else names
    # A writer's temps are hidden (``.<stem>...``): listed under the empty stem.
    gone = missing_latest(shot.stem, names.get(shot.stem, []) + names.get("", []))
    if gone is not None:
        return _row(shot, gone, review_path(shot.folder, shot.stem, gone), names, status=MISSING,
                    missing=missing_fill(shot.folder, shot.stem, gone).name, decision=None, model="", takes=0, created="")  # fmt: skip
    info = cached(path, layer_info) or {}
    d = _decision(shot, names)
    return _row(shot, n, path, names, status=(d or {}).get("status") or "pending", decision=d,
                model=str(info.get("model", "")), takes=int(info.get("takes", 1) or 1),
                created=str(info.get("createdAt") or ""))  # fmt: skip


def listing(roots: list[Path]) -> list[dict]:
    """Every shot's summary, newest first: those waiting for a decision, then the decided.
    Each folder is listed once for all its shots (a glob per shot made a folder of N shots
    cost N listings of N names)."""
    names: dict[Path, dict[str, list[str]]] = {}
    rows = []
    for s in scan(roots):
        if s.folder not in names:
            names[s.folder] = folder_names(s.folder)
        rows.append(summary(s, names[s.folder]))
    rows.sort(key=lambda r: (r["status"] != "pending", -r["mtime"], r["key"]))
    return rows
