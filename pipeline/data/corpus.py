"""A training corpus: several capture sources on different rigs, on the model skeleton at the
model's rate, cached as memory-mapped arrays with a manifest; windows drawn by source weight.

A corpus is described in a small TOML (or JSON) file::

    name = "open-v1"
    fps = 30                                   # the model's rate (default 30)
    [[source]]
    name = "bandai"
    path = "${TWEEN_DATA}/bandai_namco"        # relative paths: from the file's folder
    split = "train"                            # only the Bandai train split (pipeline.data.split)
    licence = "CC BY-NC 4.0"
    weight = 1.0                               # share of training windows (normalised)
    [[source]]
    name = "cmu"
    path = "${TWEEN_DATA}/cmu_iclone"
    include = "001_*,002_*,003_*"              # file-name globs; exclude = "..." drops some
    mapping = "cc_rig.json"                    # optional: the rig's joint mapping (as --mapping)
    licence = "CMU Graphics Lab Motion Capture Database terms"

:func:`prepare` reads every file of every source with a reader the caller gives (the fill's own
mapping and retargeting, ``pipeline.train.corpus``: this layer does not read USD) and appends
it to the source's arrays; memory follows one clip. Rotations are stored as int16 (1/32767,
under 0.005° a joint), roots as float32 cm: 180 bytes a frame, 194 MB for 10 hours at 30 fps.
Each source's manifest is rewritten atomically every ``commit_s`` seconds, saying how many
frames are valid, so an interrupted prepare resumes from its last commit (bytes past it are
cut off). A file that cannot be read is one stderr line naming it; the others go on.
:func:`open_corpus` maps the arrays as one :class:`~pipeline.data.cache.ClipSet` whose clip
``weights`` make each source's share of windows its weight.
"""

from __future__ import annotations

import fcntl
import fnmatch
import hashlib
import json
import os
import re
import shutil
import sys
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pipeline import jsonfile
from pipeline.atomic import replacing
from pipeline.data.cache import ClipSet
from pipeline.data.skeletons import bandai_skeleton
from pipeline.data.split import is_eval, shared_data_dir
from pipeline.data.terms import forbids_training
from pipeline.errors import TweenError
from pipeline.inputs import read_small_text
from pipeline.motion.rotations import quat_normalize
from pipeline.options import MAX_TEXT, one_line
from pipeline.progress import interval

KIND, VERSION = "tween-corpus", 1
MANIFEST, SOURCE_MANIFEST = "corpus.json", "clips.json"
ROT_SCALE = 32767.0
#: name → (dtype, shape of one frame's entry) of each source's arrays.
ARRAYS = {"rotations": ("<i2", (21, 4)), "roots": ("<f4", (3,))}
_SOURCE_KEYS = {"name", "path", "licence", "weight", "include", "exclude", "split", "mapping"}
#: A source's weight: a share, from one in a million to a million times another's (a smaller
#: one, 1e-320, is no normal number, and weights summing to nothing draw nothing).
WEIGHTS = (1e-6, 1e6)


class CorpusError(TweenError):
    """A corpus description or cache that cannot be used; one line naming the file."""


@dataclass(frozen=True)
class Source:
    name: str
    path: Path
    licence: str
    weight: float = 1.0
    include: str | None = None  # comma-separated file-name globs
    exclude: str | None = None
    split: str | None = None  # "train": the Bandai split's train clips only
    mapping: Path | None = None  # a joint mapping file for this rig (`tween fill --mapping`)

    def key(self, fps: float) -> str:
        """What decides the source's cached frames (not its licence or weight)."""
        mapping = self.mapping.read_bytes().hex() if self.mapping else ""
        ident = [str(self.path.resolve()), self.include, self.exclude, self.split, mapping, fps, VERSION]
        return hashlib.sha256(json.dumps(ident).encode()).hexdigest()[:12]


@dataclass(frozen=True)
class Corpus:
    name: str
    fps: float
    sources: tuple[Source, ...]
    file: Path


def _expand(text: str, base: Path) -> Path:
    """``${TWEEN_DATA}`` (the shared data folder, pipeline.data.split) and other variables
    expanded; a relative path is taken from ``base``."""
    text = text.replace("${TWEEN_DATA}", str(shared_data_dir()))
    return base / os.path.expandvars(text)


def _source(d, i: int, path: Path, base: Path) -> Source:
    where = f"{path}: source {i + 1}"
    if not isinstance(d, dict):
        raise CorpusError(f"{where}: expected a table ([[source]])")
    unknown = sorted(set(d) - _SOURCE_KEYS)
    if unknown:
        raise CorpusError(f"{where}: unknown key(s) {unknown}; known: {sorted(_SOURCE_KEYS)}")
    for key in ("name", "path", "licence"):
        if not isinstance(d.get(key), str) or not d[key].strip():
            raise CorpusError(f"{where}: {key!r} must be a non-empty string")
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]*", d["name"]):
        raise CorpusError(f"{where}: name {d['name']!r}: letters, digits, '_', '.', '-' only")
    banned = forbids_training(d["licence"])
    if banned:
        raise CorpusError(
            f"{where} ({d['name']}): licence {d['licence']!r} does not allow training a model that "
            f"ships ({banned!r}: no derivatives, research only or no training; issue 30's data rule)"
        )
    w = d.get("weight", 1.0)
    if isinstance(w, bool) or not isinstance(w, int | float) or not WEIGHTS[0] <= w <= WEIGHTS[1]:
        raise CorpusError(
            f"{where} ({d['name']}): 'weight' must be a positive number from {WEIGHTS[0]:g} "
            f"to {WEIGHTS[1]:g}, not {w!r}"
        )
    for key in ("include", "exclude", "mapping"):
        if key in d and not isinstance(d[key], str):
            raise CorpusError(f"{where} ({d['name']}): {key!r} must be a string")
    if d.get("split") not in (None, "train"):
        raise CorpusError(f"{where} ({d['name']}): 'split' is \"train\" or absent, not {d['split']!r}")
    src = Source(d["name"], _expand(d["path"], base), d["licence"], float(w), d.get("include"),
                 d.get("exclude"), d.get("split"), _expand(d["mapping"], base) if "mapping" in d else None)  # fmt: skip
    if not src.path.is_dir():
        raise CorpusError(f"{where} ({src.name}): {src.path}: no such folder")
    if src.mapping and not src.mapping.is_file():
        raise CorpusError(f"{where} ({src.name}): mapping {src.mapping}: no such file")
    return src


#: The most bytes a corpus file may hold (a few KB): a pipe or a device in its place blocked
#: or ate memory (read_small_text).
TOML_LIMIT = 8 << 20


def load_corpus(path: str | Path) -> Corpus:
    """The corpus described in ``path`` (TOML, or JSON for a ``.json`` file); CorpusError in
    one line naming the file and what is wrong."""
    path = Path(path)
    try:
        text = read_small_text(path, TOML_LIMIT, "corpus file")
        d = jsonfile.loads(text) if path.suffix == ".json" else tomllib.loads(text)
    except FileNotFoundError:
        raise CorpusError(f"{path}: no such corpus file") from None
    except (OSError, UnicodeDecodeError, ValueError) as e:
        raise CorpusError(f"{path}: cannot read: {str(e).splitlines()[0]}") from None
    except RecursionError:  # tomllib's, on arrays nested tens of thousands deep
        raise CorpusError(f"{path}: cannot read: arrays or tables nested too deeply to read") from None
    if not isinstance(d, dict):
        raise CorpusError(f"{path}: expected a table of name, fps and [[source]]")
    unknown = sorted(set(d) - {"name", "fps", "source"})
    if unknown:
        raise CorpusError(f"{path}: unknown key(s) {unknown}; known: fps, name, source")
    name = d.get("name", path.stem)
    if not isinstance(name, str) or not one_line(name):
        raise CorpusError(
            f"{path}: 'name' must be a non-empty string on one line, at most {MAX_TEXT} characters, not {name!r}"
        )
    fps = d.get("fps", 30.0)
    if isinstance(fps, bool) or not isinstance(fps, int | float) or not 1 <= fps <= 1000:
        raise CorpusError(f"{path}: 'fps' must be a number from 1 to 1000, not {fps!r}")
    raw = d.get("source")
    if not isinstance(raw, list) or not raw:
        raise CorpusError(f"{path}: no [[source]] tables")
    base = path.resolve().parent
    sources = tuple(_source(s, i, path, base) for i, s in enumerate(raw))
    _distinct(path, sources)
    return Corpus(name, float(fps), sources, path.resolve())


def _distinct(path: Path, sources: tuple[Source, ...]) -> None:
    """CorpusError where two sources share a name, or read the same files (the same folder,
    include, exclude and split): their clips would count twice."""
    names = [s.name for s in sources]
    if len(set(names)) < len(names):
        raise CorpusError(f"{path}: source names repeat: {names}")
    seen = {}
    for s in sources:
        files = (str(s.path.resolve()), s.include, s.exclude, s.split)
        if files in seen:
            raise CorpusError(
                f"{path}: sources {seen[files]!r} and {s.name!r} read the same files ({s.path}, "
                f"include {s.include!r}): their clips would count twice"
            )
        seen[files] = s.name


def source_files(src: Source, listing) -> list[Path]:
    """The files of ``src``: ``listing(folder, include)`` (pipeline.usd.take.take_files), less
    ``exclude`` and, with ``split = "train"``, less the Bandai eval split."""
    files = listing(src.path, src.include)
    drop = [p.strip() for p in (src.exclude or "").split(",") if p.strip()]
    return [
        f
        for f in files
        if not any(fnmatch.fnmatch(f.name, q) for q in drop) and not (src.split == "train" and is_eval(f))
    ]


# --- the cache -----------------------------------------------------------------------------


def _write_json(path: Path, data: dict) -> None:
    """``data`` to ``path`` atomically, readable as the arrays are."""
    with replacing(path) as tmp:
        tmp.write_text(json.dumps(data, indent=1), encoding="utf-8")


def _bytes(name: str, frames: int) -> int:
    dtype, shape = ARRAYS[name]
    return frames * int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize


class _SourceWriter:
    """Appends clips to one source's arrays; :meth:`commit` makes them count (atomically)."""

    def __init__(self, folder: Path, key: str):
        self.folder = folder
        path = folder / SOURCE_MANIFEST
        m = json.loads(path.read_text()) if path.is_file() else None
        if not m or m.get("key") != key:  # new, or its description changed: start again
            folder.mkdir(parents=True, exist_ok=True)
            m = {"key": key, "frames": 0, "clips": [], "failed": []}
        self.manifest = m
        self.files = {}
        for name in ARRAYS:
            f = folder / f"{name}.bin"
            f.touch()
            with open(f, "r+b") as h:  # what an interrupted prepare wrote past its last commit
                h.truncate(_bytes(name, m["frames"]))
            self.files[name] = open(f, "ab")

    def add(self, file: Path, rot: np.ndarray, root: np.ndarray) -> None:
        n = len(rot)
        q = np.round(quat_normalize(np.asarray(rot, np.float64)) * ROT_SCALE).astype("<i2")
        self.files["rotations"].write(np.ascontiguousarray(q).tobytes())
        self.files["roots"].write(np.ascontiguousarray(root, "<f4").tobytes())
        start = self.manifest["frames"]
        self.manifest["clips"].append({"file": str(file), "start": start, "frames": n})
        self.manifest["frames"] = start + n

    def commit(self) -> None:
        for h in self.files.values():
            h.flush()
            os.fsync(h.fileno())
        _write_json(self.folder / SOURCE_MANIFEST, self.manifest)

    def close(self) -> None:
        for h in self.files.values():
            h.close()


def _why(file: Path, e: Exception) -> tuple[str, str]:
    """Why ``file`` could not be read, and its one ``tween: skipped clip:`` line."""
    msg = str(e).splitlines()[0] if str(e) else type(e).__name__
    line = msg if str(file) in msg else f"{file}: {msg}"
    return msg, f"tween: skipped clip: {line}"


def _summary(corpus: Corpus, out: Path, complete: bool) -> dict:
    """The corpus manifest from each source's: clips, frames, hours, failures, licence, weight."""
    rows = []
    for src in corpus.sources:
        p = out / src.name / SOURCE_MANIFEST
        m = json.loads(p.read_text()) if p.is_file() else {"frames": 0, "clips": [], "failed": []}
        rows.append({"name": src.name, "path": str(src.path), "licence": src.licence, "weight": src.weight,
                     "key": src.key(corpus.fps), "clips": len(m["clips"]), "frames": m["frames"],
                     "hours": round(m["frames"] / corpus.fps / 3600.0, 4), "failed": m["failed"]})  # fmt: skip
    frames = sum(r["frames"] for r in rows)
    return {"kind": KIND, "version": VERSION, "name": corpus.name, "description": str(corpus.file),
            "fps": corpus.fps, "skeleton": list(bandai_skeleton().names), "complete": complete,
            "clips": sum(r["clips"] for r in rows), "frames": frames,
            "hours": round(frames / corpus.fps / 3600.0, 4), "sources": rows}  # fmt: skip


def prepare(
    corpus: Corpus, out: str | Path, read, listing, progress: bool = True, commit_s: float = 30.0
) -> dict:
    """Reads every source of ``corpus`` into ``out`` (resuming what an earlier call left) and
    returns the manifest (also ``out/corpus.json``). ``read(path, source, fps)`` gives a clip
    on the model skeleton at ``fps`` (a Motion); ``listing(folder, include)`` a source's files.

    CorpusError, one line naming the corpus file and the source, where a source lists no file,
    two sources hold the same file (both before anything is written), or a source yields no
    frame at all (its weight could not be honoured; a folder this call made is removed)."""
    out = Path(out)
    files = _listed(corpus, listing)
    made = [d for d in (out, *out.parents) if not d.exists()]  # out, then the folders it is in
    out.mkdir(parents=True, exist_ok=True)
    try:
        with open(out / ".lock", "w") as lock:
            # Two prepares appending to the same arrays would interleave their clips, so one
            # waits for the other; it then finds the clips committed and reads only what is
            # left (two trainings started on the same corpus both go on).
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                print(f"tween: {out}: being prepared by another process; waiting for it", file=sys.stderr)
                fcntl.flock(lock, fcntl.LOCK_EX)
            return _prepare(corpus, out, files, read, progress, commit_s)
    except CorpusError:
        _unmake(made)  # bad input leaves no half-made cache entry behind
        raise


def _unmake(made: list[Path]) -> None:
    """Removes ``made[0]`` (a cache folder this call made) and then those of the folders it is
    in that this call made and that are empty: another prepare may have put its own there."""
    if made:
        shutil.rmtree(made[0], ignore_errors=True)
    for d in made[1:]:
        try:
            d.rmdir()
        except OSError:
            return


def _listed(corpus: Corpus, listing) -> list[list[Path]]:
    """Each source's files; CorpusError naming the corpus and the source where a source lists
    none, or where two sources hold the same file (its clip would count twice)."""
    out, owner = [], {}
    for src in corpus.sources:
        try:
            files = source_files(src, listing)
        except TweenError as e:
            raise CorpusError(f"{corpus.file}: source {src.name!r}: {str(e).splitlines()[0]}") from None
        if not files:
            raise CorpusError(f"{corpus.file}: source {src.name!r}: no file left in {src.path} (include, "
                              "exclude and split leave none)")  # fmt: skip
        for f in files:
            other = owner.setdefault(str(Path(f).resolve()), src.name)
            if other != src.name:
                raise CorpusError(f"{corpus.file}: sources {other!r} and {src.name!r} both hold {f}: "
                                  "its clip would count twice")  # fmt: skip
        out.append(files)
    return out


def _prepare(corpus: Corpus, out: Path, listed, read, progress: bool, commit_s: float) -> dict:
    todo = []
    for src, files in zip(corpus.sources, listed, strict=True):
        writer = _SourceWriter(out / src.name, src.key(corpus.fps))
        done = {c["file"] for c in writer.manifest["clips"]}
        writer.manifest["failed"] = []  # tried again: a file fixed since is read
        todo.append((src, writer, [f for f in files if str(f) not in done]))
    n = sum(len(t[2]) for t in todo)
    # Shown in a log as on a terminal: a long prepare says how far it is wherever it runs.
    bar = tqdm(total=n, desc=f"corpus {corpus.name}", unit="clip", file=sys.stderr, disable=not progress,
               mininterval=max(2.0, interval()), delay=1.0)  # fmt: skip
    try:
        for src, writer, files in todo:
            bar.set_postfix_str(src.name, refresh=False)
            _read_source(corpus, out, src, writer, files, read, bar, commit_s)
    finally:
        for _, writer, _ in todo:
            writer.close()
        bar.close()
    manifest = _summary(corpus, out, True)
    _write_json(out / MANIFEST, manifest)
    return manifest


def _read_source(corpus: Corpus, out: Path, src: Source, writer, files, read, bar, commit_s) -> None:
    """Appends the clips of ``files`` to ``writer``. A file that cannot be read is one line; while
    the source has no frame those lines wait, and a source that ends with none is one
    CorpusError instead (its share of the windows cannot be honoured)."""
    last, waiting = time.monotonic(), []
    for f in files:
        try:
            m = read(f, src, corpus.fps)
            if len(m) < 2:
                raise ValueError("fewer than two frames")
        except (TweenError, ValueError, IndexError, OSError, KeyError) as e:
            why, line = _why(f, e)
            writer.manifest["failed"].append({"file": str(f), "why": why})
            waiting.append(line)
        else:  # a full disk while writing is no bad clip: it stops the prepare
            writer.add(f, m.rotations, m.root_positions)
        if writer.manifest["frames"]:
            for line in waiting:
                print(line, file=sys.stderr)
            waiting = []
        bar.update()
        if time.monotonic() - last > commit_s:
            writer.commit()
            _write_json(out / MANIFEST, _summary(corpus, out, False))
            last = time.monotonic()
    writer.commit()
    if not writer.manifest["frames"]:
        first = writer.manifest["failed"][0]["why"] if writer.manifest["failed"] else "no file"
        raise CorpusError(
            f"{corpus.file}: source {src.name!r}: none of its {len(files)} file(s) could be read "
            f"(first: {first}), so its weight {src.weight:g} cannot be honoured"
        )


class Frames:
    """Frames of several memory-mapped sources as one (N, ...) float32 array, for slices that
    stay within one source (a clip's frames): what training batches read."""

    def __init__(self, parts: list[np.ndarray], scale: float | None, shape: tuple[int, ...]):
        self.parts, self.scale = parts, scale
        self.bounds = np.cumsum([0] + [len(p) for p in parts])
        self.shape = (int(self.bounds[-1]), *shape)
        self.dtype = np.dtype(np.float32)

    def __len__(self) -> int:
        return self.shape[0]

    def __reduce__(self):
        # Sent to batch-making processes (--workers) as file names, not as the frames: each
        # maps the files itself, and the host keeps one copy in its page cache.
        files = [(p.filename, p.dtype.str, p.shape) for p in self.parts]
        return (_reopened, (files, self.scale, self.shape[1:]))

    def _decode(self, a: np.ndarray) -> np.ndarray:
        a = np.asarray(a, np.float32)
        return quat_normalize(a / self.scale).astype(np.float32) if self.scale else a

    def __getitem__(self, key):
        if isinstance(key, np.ndarray) and key.dtype.kind in "iu":  # frames picked (a pose bank)
            part = np.searchsorted(self.bounds, key, side="right") - 1
            out = np.empty((len(key), *self.shape[1:]), np.float32)
            for i in np.unique(part):
                at = part == i
                out[at] = self._decode(self.parts[i][key[at] - self.bounds[i]])
            return out
        if not isinstance(key, slice) or key.step not in (None, 1):
            raise TypeError("corpus frames are read as contiguous slices or index arrays")
        start, stop, _ = key.indices(self.shape[0])
        if stop <= start:
            return np.zeros((0, *self.shape[1:]), np.float32)
        i = int(np.searchsorted(self.bounds, start, side="right")) - 1
        lo = int(self.bounds[i])
        if stop > self.bounds[i + 1]:
            raise IndexError(f"frames {start}:{stop} cross sources")
        return self._decode(self.parts[i][start - lo : stop - lo])


def _reopened(files, scale, shape) -> Frames:
    return Frames([np.memmap(f, dtype=d, mode="r", shape=tuple(n)) for f, d, n in files], scale, shape)


def open_corpus(out: str | Path, corpus: Corpus | None = None) -> ClipSet:
    """The prepared corpus at ``out`` as one ClipSet of memory maps (names ``source/file``),
    its clip ``weights`` each source's weight shared over its clips by frames; with ``corpus``
    the weights are that description's (they change nothing cached)."""
    out = Path(out)
    try:
        m = json.loads((out / MANIFEST).read_text())
    except (OSError, ValueError) as e:
        raise CorpusError(f"{out / MANIFEST}: cannot read (prepare the corpus first): {e}") from None
    if m.get("kind") != KIND or m.get("version") != VERSION or not m.get("complete"):
        raise CorpusError(f"{out / MANIFEST}: not a complete {KIND} v{VERSION} (prepare it again)")
    weight = {s.name: s.weight for s in corpus.sources} if corpus else {}
    names, lengths, weights, groups, rots, roots = [], [], [], [], [], []
    for row in m["sources"]:
        sm = json.loads((out / row["name"] / SOURCE_MANIFEST).read_text())
        F = int(sm["frames"])
        if not F:
            continue
        maps = {}
        for name, (dtype, shape) in ARRAYS.items():
            f = out / row["name"] / f"{name}.bin"
            if f.stat().st_size < _bytes(name, F):
                raise CorpusError(f"{f}: shorter than its manifest's {F} frames (prepare it again)")
            maps[name] = np.memmap(f, dtype=dtype, mode="r", shape=(F, *shape))
        rots.append(maps["rotations"])
        roots.append(maps["roots"])
        w = weight.get(row["name"], row["weight"])
        for c in sm["clips"]:
            names.append(f"{row['name']}/{Path(c['file']).name}")
            lengths.append(c["frames"])
            weights.append(w * c["frames"] / F)
            groups.append(len(rots) - 1)
    if not names:
        raise CorpusError(f"{out}: the corpus holds no frames")
    lengths = np.array(lengths, np.int64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    rot = Frames(rots, ROT_SCALE, (21, 4))
    roots_ = Frames(roots, None, (3,))
    return ClipSet(names, starts, lengths, rot, roots_, float(m["fps"]), np.array(weights), np.array(groups))
