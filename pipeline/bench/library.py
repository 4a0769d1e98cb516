"""The library bench: a studio's own takes as the in-betweener, measured on takes held out of it.

What a studio that hands over its library gets on new shots of the same characters and kinds
of motion. A source is split **by take**: the held-out takes are shots, the other takes are
the library (``tween library build``); nothing held out is in the library, and nothing here
trains. Each held-out take goes the product's path (``tween convert --fps 30 --keys-every N``,
the fill API as ``tween fill-local --library`` runs it) and is scored in the rig's own world
joint positions between the keys (:func:`pipeline.bench.studio.evaluate_take`).

Sources and their splits (never the sources issue 30 reserves for independent measurement):

- ``cmu``: the CMU takes of ``../shared/data/cmu_iclone`` (100-joint Character Creator rig,
  60 fps), every fifth take of each subject (its 5th, 10th, …) held out;
- ``bandai``: the Bandai train split (the protocol's eval split is not used), the dataset-2
  takes whose number is 4 mod 5 held out (every ``--stride``-th of them is scored);
- ``others`` (not in the default run): other actors, split **by subject**: the library is every
  take the default may train on (the Bandai train split and CMU subjects 1–3,
  ``pipeline/data/corpora/bandai-cmu123.toml``), the held-out takes are CMU subjects 5–7's.
  What the capture the product may ship does for actors and a lab it never saw (issue 30).

Methods: ``library`` (the product's fill with ``--library LIB``: the library and the shipped
network each probed on the shot's keys, the better trusted against the spline, the network
only by the library's margin),
``library-spline`` (the library trusted against the spline, the network not consulted),
``library-alone`` (``--library LIB --trust model``: its per-gap windows and spline fallback,
unchecked by probes), ``default`` (the shipped network's trusted fill), ``spline``. On the
Bandai split the shipped network was trained on the held-out takes too (they are train-split
takes), so there ``library-spline`` is the clean measure of the library.

``python -m pipeline.bench.library [--source cmu,bandai,others] [--every 10,30] [--stride 5]
[--max-frames 300] [--methods library,library-spline,library-alone,default,spline] [--tuning]
[--out DIR]``; ``--tuning`` measures the split the constants are chosen on instead (:func:`split`).
"""

from __future__ import annotations

import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pipeline.arguments import Parser
from pipeline.bench import args as arg
from pipeline.bench.heldout import cmu_files
from pipeline.bench.report import publish
from pipeline.bench.studio import evaluate_take
from pipeline.data.cache import cache_dir
from pipeline.data.split import list_clips
from pipeline.errors import TweenError
from pipeline.infer.api import load_model
from pipeline.library.store import is_library

METHODS = ("library", "library-spline", "library-alone", "default", "spline")
SOURCES = ("cmu", "bandai")  # the default run's
ALL_SOURCES = (*SOURCES, "others")
#: ``others``: the CMU subjects in the library (trainable) and those held out (docs/models.md).
OTHERS_LIBRARY, OTHERS_HELD = (1, 2, 3), (5, 6, 7)
#: Why ``others`` has no tuning split (split's error and the CLI's refusal).
NO_TUNING = "others: no tuning split (its held-out subjects are never tuned on)"
_TAKE = re.compile(r"_(\d+)\.bvh(\.gz)?$")


def split(source: str, tuning: bool = False) -> tuple[list[Path], list[Path]]:
    """(library takes, held-out takes) of a source, split by take; ``tuning``: the split the
    constants of :mod:`pipeline.library` are chosen on (CMU: every subject's 3rd, 8th, … take
    held out; Bandai: the dataset-2 takes numbered 3 mod 5), never the bench's."""
    if source == "cmu":
        files = cmu_files()
        by: dict[str, list[Path]] = {}
        for f in files:
            by.setdefault(f.name[:3], []).append(f)
        held = {f for fs in by.values() for i, f in enumerate(fs) if i % 5 == (2 if tuning else 4)}
    elif source == "bandai":
        files = list_clips("train")
        rest = 3 if tuning else 4
        held = {
            f for f in files if f.name.startswith("dataset-2_") and int(_TAKE.search(f.name)[1]) % 5 == rest
        }
    elif source == "others":
        if tuning:
            raise ValueError(NO_TUNING)
        return list_clips("train") + cmu_files(OTHERS_LIBRARY), cmu_files(OTHERS_HELD)
    else:
        raise ValueError(f"unknown source {source!r} (one of {', '.join(ALL_SOURCES)})")
    return [f for f in files if f not in held], sorted(held)


def library_for(source: str, files: list[Path], tuning: bool = False) -> Path:
    """The source's library (built once into the cache, as ``tween library build`` builds it)."""
    from pipeline.library.build import build

    folder = cache_dir() / "bench-libraries" / f"{source}-{'tuning' if tuning else 'split'}-v1"
    if not is_library(folder):
        print(f"library bench: building the {source} library from {len(files)} takes…", file=sys.stderr)
        tmp = folder.with_name(folder.name + ".partial")
        if tmp.exists():
            shutil.rmtree(tmp)
        build(None, tmp, files=files, licence="as the source's", name=f"{source}-split")
        tmp.rename(folder)
    return folder


def subjects_library(out: Path, subjects: tuple[int, ...]) -> Path:
    """The library of these CMU subjects' takes, ``out/library-cmu-1-2-3`` (built once), as the
    offline studies of a shipped library use it (experiments/shipped_library.py, library_margin.py)."""
    from pipeline.library.build import build

    lib = Path(out) / f"library-cmu-{'-'.join(map(str, subjects))}"
    if not is_library(lib):
        build(None, lib, files=cmu_files(subjects), licence="CMU Graphics Lab terms", name=lib.name)
    return lib


def fills_for(lib: Path, model: str = "default") -> dict:
    """Each method's fill options (``FillOptions`` fields) with the library ``lib``; ``model``:
    the network probed beside it and filling ``default`` (a studio's fine-tune, ``--model``)."""
    return {
        "library": {"library": str(lib), "model": model, "trust": "auto"},
        "library-spline": {"library": str(lib), "model": model, "trust": "auto"},
        "library-alone": {"library": str(lib), "model": model, "trust": "model"},
        "default": {"model": model, "trust": "auto"},
        "spline": {"model": "spline", "trust": "auto"},
    }


def run(sources=SOURCES, every=(10, 30), methods=METHODS, stride: int = 5, max_frames: int | None = 300,
        limit: int | None = None, tuning: bool = False, model: str = "default") -> dict:  # fmt: skip
    report: dict = {"every": list(every), "methods": list(methods), "max_frames": max_frames, "model": model,
                    "sources": {}}  # fmt: skip
    if tuning:
        report["split"] = "tuning"
    t0 = time.perf_counter()
    for source in sources:
        lib_files, held = split(source, tuning)
        lib = library_for(source, lib_files, tuning)
        if source == "bandai":
            held = held[::stride]
        held = held[: limit or None]
        per: dict = {int(e): {} for e in every}
        with tempfile.TemporaryDirectory(prefix="tween-library-bench-") as tmp:
            for i, f in enumerate(held):
                for e in every:
                    print(f"library bench: {source} take {i + 1}/{len(held)} {f.name}, keys every {e}…",
                          file=sys.stderr)  # fmt: skip
                    per[int(e)][f.name] = evaluate(
                        f, int(e), methods, Path(tmp), max_frames, fills_for(lib, model)
                    )
        report["sources"][source] = {"library_takes": len(lib_files), "held_out": [f.name for f in held],
                                     "per_take": per, "summary": summary(per, methods)}  # fmt: skip
    report["seconds"] = time.perf_counter() - t0
    report["markdown"] = markdown(report)
    return report


def evaluate(path: Path, every: int, methods, work: Path, max_frames, fills: dict) -> dict:
    """evaluate_take, with ``library-spline`` filled without the network's probes."""
    from pipeline.fill import api

    res = evaluate_take(path, every, [m for m in methods if m != "library-spline"], work, max_frames, True, 30.0,
                        fills=fills)  # fmt: skip
    if "library-spline" in methods:
        api.LIBRARY_VS_NETWORK = False
        try:
            alone = evaluate_take(path, every, ["library-spline"], work, max_frames, True, 30.0, fills=fills)
        finally:
            api.LIBRARY_VS_NETWORK = True
        res["methods"]["library-spline"] = alone["methods"]["library-spline"]
    return res


def summary(per: dict, methods) -> dict:
    """Per key spacing: each method's pooled error (cm, mapped joints) and its ratio to the
    spline's, pooled and per take (median, worst)."""
    out = {}
    for e, takes in per.items():
        row = {}
        for m in methods:
            err = sum(t["methods"][m]["mapped_sum"] for t in takes.values()) / max(
                1, sum(t["methods"][m]["mapped_n"] for t in takes.values())
            )
            ratios = [
                t["methods"][m]["mapped_sum"] / max(t["methods"]["spline"]["mapped_sum"], 1e-9)
                for t in takes.values()
            ]
            row[m] = {"cm": err, "median_take": float(np.median(ratios)), "worst_take": float(max(ratios))}
        for m in methods:
            row[m]["vs_spline"] = row[m]["cm"] / max(row["spline"]["cm"], 1e-9)
        out[e] = row
    return out


def markdown(rep: dict) -> str:
    lines = [
        f"Held-out takes (first {rep['max_frames']} frames at 30 fps), converted, blocked, filled and "
        "scored on their own rig: mapped joints' world error (cm) between the keys; ÷ spline pooled "
        "(median take, worst take)."
        + ("" if rep.get("model", "default") == "default" else f" The network: {rep['model']}."),
        "",
        "| source | keys every | " + " | ".join(rep["methods"]) + " |",
        "|---|---|" + "---|" * len(rep["methods"]),
    ]
    for source, r in rep["sources"].items():
        for e, row in r["summary"].items():
            cells = [
                f"{row[m]['cm']:.2f} cm, {row[m]['vs_spline']:.3f} ({row[m]['median_take']:.2f}, "
                f"{row[m]['worst_take']:.2f})"
                for m in rep["methods"]
            ]
            lines.append(f"| {source} ({len(r['held_out'])} takes) | {e} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = Parser(prog="python -m pipeline.bench.library", description=__doc__.splitlines()[0])
    ap.add_argument("--source", default=",".join(SOURCES), help="comma-separated: " + ", ".join(ALL_SOURCES))
    ap.add_argument(
        "--every",
        type=arg.spacings,
        default=(10, 30),
        help="key spacings, comma-separated frames (of the shot)",
    )
    ap.add_argument("--methods", default=",".join(METHODS), help="comma-separated: " + ", ".join(METHODS))
    ap.add_argument("--stride", type=arg.stride, default=5, help="bandai: every N-th held-out take is scored")
    ap.add_argument("--limit", type=arg.count, default=None, help="at most N held-out takes per source")
    ap.add_argument(
        "--max-frames", type=arg.frames_or_all, default=300, help="frames of each take at 30 fps (0: all)"
    )
    ap.add_argument("--tuning", action="store_true",
                    help="the tuning split (where the constants are chosen), not the bench's")  # fmt: skip
    ap.add_argument("--model", default="default",
                    help="the network beside the library and in 'default': a name or model folder (a studio's fine-tune)")  # fmt: skip
    ap.add_argument("--out", type=Path, default=None, help="folder for library.json and library.md")
    a = ap.parse_args(argv)
    methods = tuple(m for m in a.methods.split(",") if m)
    bad = [m for m in methods if m not in METHODS]
    if bad or "spline" not in methods:
        ap.error(f"--methods: one or more of {', '.join(METHODS)}, spline included")
    sources = tuple(s for s in a.source.split(",") if s)
    if any(s not in ALL_SOURCES for s in sources):
        ap.error(f"--source: one or more of {', '.join(ALL_SOURCES)}")
    if a.tuning and "others" in sources:
        ap.error(f"--tuning: {NO_TUNING}")
    try:  # a model that is not there (or is damaged) is one line naming it, before the library is built
        load_model(a.model)
    except FileNotFoundError as e:
        raise TweenError(f"--model {a.model}: {e}") from None
    rep = run(sources, a.every, methods, a.stride, a.max_frames or None, a.limit, a.tuning, a.model)
    publish(rep, a.out, "library")
    return 0


if __name__ == "__main__":
    from pipeline.command import run_main
    from pipeline.data.cache_paths import cache_root

    run_main(main, log_dir=cache_root() / "logs")  # a bug's traceback goes there, as tween's
