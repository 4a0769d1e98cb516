"""Parsed clips of a split, cached as one .npz so a second run takes seconds."""

from __future__ import annotations

import hashlib
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pipeline.atomic import replacing
from pipeline.data.cache_paths import cache_dir, cache_root  # noqa: F401 (re-exported)
from pipeline.data.split import list_clips
from pipeline.motion.bvh import read_bvh
from pipeline.progress import interval

CACHE_VERSION = 1


@dataclass
class ClipSet:
    """Clips concatenated: rotations (N, J, 4) continuous per clip, roots (N, 3), clip bounds."""

    names: list[str]
    starts: np.ndarray  # (C,) first frame of each clip in the flat arrays
    lengths: np.ndarray  # (C,)
    rotations: np.ndarray
    roots: np.ndarray
    fps: float
    #: (C,) how often each clip's windows are drawn, relative (None: every clip alike), and
    #: (C,) the group (a corpus's source, pipeline.data.corpus) each clip belongs to.
    weights: np.ndarray | None = None
    groups: np.ndarray | None = None

    def draw_p(self, ok: np.ndarray) -> np.ndarray | None:
        """Probabilities of drawing each clip of ``ok`` (indices of the clips long enough for a
        window); None: every clip alike. Each group keeps its whole weight, shared over its
        clips in ``ok``: a source's short clips do not lower its share of windows."""
        if self.weights is None:
            return None
        w = np.asarray(self.weights, np.float64)
        g = np.zeros(len(w), np.int64) if self.groups is None else np.asarray(self.groups)
        full = np.bincount(g, weights=w)
        have = np.bincount(g[ok], weights=w[ok], minlength=len(full))
        p = w[ok] * full[g[ok]] / have[g[ok]]
        return p / p.sum()

    def clip(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        s, n = self.starts[i], self.lengths[i]
        return self.rotations[s : s + n], self.roots[s : s + n]

    def __len__(self) -> int:
        return len(self.names)


def load_split(split: str, limit: int | None = None, root: Path | None = None) -> ClipSet:
    """Every clip of ``split`` read with the protocol's rules, quaternions continuous per clip."""
    files = list_clips(split, root)
    if limit:
        files = files[:limit]
    return load_files(files, split)


def load_files(files: list[Path], split: str, read=None) -> ClipSet:
    """``files`` as one ClipSet, cached under ``split``'s name. ``read`` (path -> Motion on the
    model skeleton) defaults to the protocol's BVH reading; another reader names its own cache
    (``split``) and gets the files' sizes and times in its key, as a studio's clips change."""
    ident = "\n".join(str(f) for f in files)
    if read is not None:
        ident += "".join(f"|{f.stat().st_size}:{f.stat().st_mtime_ns}" for f in files)
    key = hashlib.sha1((ident + f"v{CACHE_VERSION}").encode()).hexdigest()[:12]
    path = cache_dir() / f"clips-{split}-{len(files)}-{key}.npz"
    if path.exists():
        cached = _read_cache(path)
        if cached is not None:
            return cached
    rots, roots, names, lengths = [], [], [], []
    fps = None
    for f in tqdm(
        files,
        desc=f"reading {split} clips" if read is None else f"reading {split}",  # "reading takes"
        file=sys.stderr,
        unit="clip",
        disable=len(files) < (50 if read is None else 2),
        mininterval=interval(),
    ):
        m = read_bvh(f).continuous() if read is None else read(f)
        fps = fps or m.fps
        rots.append(m.rotations)
        roots.append(m.root_positions)
        names.append(m.name)
        lengths.append(len(m))
    lengths = np.array(lengths, np.int64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    cs = ClipSet(names, starts, lengths, np.concatenate(rots), np.concatenate(roots), float(fps))
    # A temporary of its own (two jobs may fill the same cache at once), removed when the
    # write fails or is interrupted: a Ctrl-C while it wrote left ~120 MB of train clips.
    with replacing(path, suffix=".npz") as tmp:
        np.savez(
            tmp,
            names=np.array(names),
            starts=starts,
            lengths=lengths,
            rotations=cs.rotations,
            roots=cs.roots,
            fps=fps,
        )
    return cs


def _read_cache(path: Path) -> ClipSet | None:
    """The clip set cached at ``path``; None (with a warning: it is read again from the
    clips) where the file is damaged (cut short, not an .npz) or its arrays disagree."""
    try:
        with np.load(path, allow_pickle=False) as z:
            names, starts, lengths = list(z["names"]), z["starts"], z["lengths"]
            cs = ClipSet(names, starts, lengths, z["rotations"], z["roots"], float(z["fps"]))
        ends = np.cumsum(lengths)
        ok = (
            len(names) == len(starts) == len(lengths) > 0
            and lengths.dtype.kind in "iu"
            and starts.dtype.kind in "iu"
            and (lengths >= 0).all()
            and (starts == ends - lengths).all()
            and cs.rotations.ndim == 3
            and cs.rotations.shape[-1] == 4
            and cs.roots.shape == (int(ends[-1]), 3)
            and len(cs.rotations) == int(ends[-1])
            and np.isfinite(cs.fps)
            and cs.fps > 0
        )
    except Exception:  # a cut or foreign file: zip, zlib, EOF, key and value errors alike
        ok = False
    if ok:
        return cs
    print(f"tween: warning: {path}: damaged clip cache; reading the clips again", file=sys.stderr)
    return None
