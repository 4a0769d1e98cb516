"""A corpus (pipeline.data.corpus) read through the fill's own path, for ``tween train --corpus``;
and a studio's folder of takes, each checked before any is read, for ``tween train --data``.

Each clip goes the way a shot goes to the model: ``pipeline.usd.take`` maps its joints (by
name, or with the source's mapping file), retargets it onto the model skeleton and resamples it
to the corpus's rate; a BVH already on the model skeleton at 30 fps is read as the protocol
reads it. The cache lives under ``$TWEEN_CACHE/corpora/`` (one folder per description file) or
where ``--out`` says::

    python -m pipeline.train.corpus corpora/open-v1.toml [--out DIR]   # prepare (resumes), print the manifest
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import stat
from pathlib import Path

from pipeline.adapt.mapping import MappingError, load_override
from pipeline.arguments import Parser
from pipeline.data.cache import cache_root
from pipeline.data.corpus import Corpus, CorpusError, load_corpus, open_corpus, prepare
from pipeline.errors import TweenError
from pipeline.inputs import not_a_file
from pipeline.motion.bvh import MAX_BYTES, is_bvh


def read_clip(path: Path, source, fps: float):
    """One clip of ``source`` on the model skeleton at ``fps``: the fill's mapping and retargeting."""
    from pipeline.usd.take import model_take, studio_take

    if source.mapping is None and abs(fps - 30.0) < 1e-6:
        return studio_take(path)  # the protocol's exact reading for Bandai's own skeleton
    return model_take(path, fps, source.mapping).continuous()


def check_mappings(corpus: Corpus) -> None:
    """Each source's mapping file read once, before any clip: CorpusError naming the corpus,
    the source and the file where one cannot be used (not one skipped clip per file)."""
    for src in corpus.sources:
        try:
            load_override(src.mapping)
        except MappingError as e:
            raise CorpusError(f"{corpus.file}: source {src.name!r}: {str(e).splitlines()[0]}") from None


def cache_folder(corpus: Corpus) -> Path:
    """Where ``corpus`` is prepared by default: one folder per description file."""
    tag = hashlib.sha256(str(corpus.file).encode()).hexdigest()[:8]
    return cache_root() / "corpora" / f"{corpus.file.stem}-{tag}"


def prepared(
    file: str | Path, out: str | Path | None = None, progress: bool = True
) -> tuple[Corpus, Path, dict]:
    """The corpus of ``file`` prepared (or resumed) at ``out`` (default :func:`cache_folder`):
    (the corpus, its folder, its manifest)."""
    from pipeline.usd.take import take_files

    corpus = load_corpus(file)
    check_mappings(corpus)
    folder = Path(out) if out else cache_folder(corpus)
    manifest = prepare(corpus, folder, read_clip, take_files, progress=progress)
    return corpus, folder, manifest


def corpus_clips(file: str | Path):
    """What ``tween train --corpus FILE`` trains on: the prepared corpus as a weighted ClipSet
    of memory maps."""
    corpus, folder, _ = prepared(file)
    return open_corpus(folder, corpus)


#: The first bytes a take may start with, by its kind: gzip, or a BVH's HIERARCHY after blank
#: lines (and a UTF-8 BOM); USD text, crate or a USDZ zip (a .usd is text or crate).
GZIP = b"\x1f\x8b"
USD_MAGIC = {".usda": (b"#usda", b"PXR-USDC"), ".usdc": (b"#usda", b"PXR-USDC"),
             ".usd": (b"#usda", b"PXR-USDC"), ".usdz": (b"PK\x03\x04",)}  # fmt: skip
#: Bytes of a take read by the check: a BVH's HIERARCHY after this many blank bytes is left
#: to the full read.
HEAD_BYTES = 4096


def _not_a_take(path: Path) -> str | None:
    """None where ``path`` is plausibly a take, from its kind, size and first bytes alone; else
    why not, as a phrase."""
    try:
        st = os.stat(path)
    except OSError as e:
        if e.errno == errno.ELOOP:
            return "a link loop (it leads back to itself), not a take file"
        return not_a_file(path, "take file")  # a link to nothing
    if stat.S_ISDIR(st.st_mode):
        return "a folder named like a take, not a take file"
    if not stat.S_ISREG(st.st_mode):
        return not_a_file(path, "take file")  # a pipe, socket or device
    if st.st_size == 0:
        return "an empty file, not a take"
    try:  # without blocking: the file may have turned into a pipe since
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                return "not a regular file (a pipe, socket or device), not a take file"
            head = os.read(fd, HEAD_BYTES)
        finally:
            os.close(fd)
    except OSError as e:
        return f"cannot read it: {e.strerror or e}"
    return _bad_head(path, head, st.st_size)


def _bad_head(path: Path, head: bytes, size: int) -> str | None:
    """Why a take of ``size`` bytes starting with ``head`` cannot be one of its kind, or None."""
    name = path.name.lower()
    if is_bvh(path):
        if head.startswith(GZIP):
            return None  # its text's size is the reader's to bound, as it inflates it
        if name.endswith(".gz"):
            return "named .gz, but not gzip data"
        if size > MAX_BYTES:
            return f"more than {MAX_BYTES >> 30} GiB of text: not a BVH take"
        text = head.removeprefix(b"\xef\xbb\xbf").lstrip()
        if text and not text.startswith(b"HIERARCHY"):
            return "not a BVH take (it does not start with HIERARCHY)"
        return None
    ext = os.path.splitext(name)[1]
    if not head.startswith(USD_MAGIC[ext]):
        kind = "a USDZ (zip) does" if ext == ".usdz" else "USD text (#usda) or a USD crate (PXR-USDC) does"
        return f"not a USD take (it does not start as {kind})"
    return None


def check_takes(folder: str | Path, include: str | None = None) -> list[Path]:
    """The takes ``tween train --data FOLDER`` reads (``take_files``), each checked first
    without reading it (a regular file, not empty, readable, within the reader's size
    bound, its first bytes those of its kind): one that is not is a TweenError naming it.
    Refused, not skipped: a studio mends its folder rather than train on part of it."""
    from pipeline.usd.take import include_globs, included, take_files, take_paths

    def unlisted(e: OSError):  # a subfolder that cannot be listed may hold takes
        raise TweenError(f"{e.filename}: --data: cannot list this folder of takes: {e.strerror or e}")

    folder = Path(folder)
    if folder.is_dir():
        # Every path named like a take, a pipe or a link that leads nowhere too (which the
        # takes listing passes over), through the listing's own walk and globs.
        globs = include_globs(include)
        named = (p for p in take_paths(folder.resolve(), onerror=unlisted) if included(p.name, globs))
        for path in sorted(named):
            if (why := _not_a_take(path)) is not None:
                raise TweenError(
                    f"{path}: {why}; --data reads every take in its folder: mend or remove this one, "
                    "or leave it out with --data-include"
                )
    return take_files(folder, include)  # no such folder, no takes: its own line


def studio_clips(folder: str | Path, include: str | None = None, limit: int | None = None):
    """What ``tween train --data FOLDER`` trains on: its takes checked (:func:`check_takes`),
    then read (``load_takes``: mapped, retargeted, cached; a take the check passes that
    fails to read is one line naming it)."""
    from pipeline.usd import take

    check_takes(folder, include)
    return take.load_takes(folder, include, limit)


def describe(manifest: dict) -> str:
    """The manifest as a table: clips, frames, hours, weight and licence per source."""
    lines = [f"corpus {manifest['name']}: {manifest['clips']} clips, {manifest['frames']} frames at "
             f"{manifest['fps']:g} fps ({manifest['hours']:.2f} h)"]  # fmt: skip
    for s in manifest["sources"]:
        failed = f", {len(s['failed'])} failed" if s["failed"] else ""
        lines.append(f"  {s['name']}: {s['clips']} clips, {s['frames']} frames ({s['hours']:.3f} h), "
                     f"weight {s['weight']:g}, licence {s['licence']}{failed}")  # fmt: skip
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = Parser(prog="python -m pipeline.train.corpus", description=__doc__.splitlines()[0])
    ap.add_argument("corpus", help="corpus description (TOML or JSON)")
    ap.add_argument("--out", help="cache folder (default: under $TWEEN_CACHE/corpora)")
    ap.add_argument("--json", action="store_true", help="print the manifest as JSON")
    args = ap.parse_args(argv)
    _, folder, manifest = prepared(args.corpus, args.out)
    print(json.dumps(manifest, indent=1) if args.json else f"{describe(manifest)}\n  cache: {folder}")
    return 0


if __name__ == "__main__":
    from pipeline.command import run_main

    run_main(main)
