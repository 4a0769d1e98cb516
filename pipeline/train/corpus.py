"""A corpus (pipeline.data.corpus) read through the fill's own path, for ``tween train --corpus``.

Each clip goes the way a shot goes to the model: ``pipeline.usd.take`` maps its joints (by
name, or with the source's mapping file), retargets it onto the model skeleton and resamples it
to the corpus's rate; a BVH already on the model skeleton at 30 fps is read as the protocol
reads it. The cache lives under ``$TWEEN_CACHE/corpora/`` (one folder per description file) or
where ``--out`` says::

    python -m pipeline.train.corpus corpora/open-v1.toml [--out DIR]   # prepare (resumes), print the manifest
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from pipeline.adapt.mapping import MappingError, load_override
from pipeline.arguments import Parser
from pipeline.data.cache import cache_root
from pipeline.data.corpus import Corpus, CorpusError, load_corpus, open_corpus, prepare


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
