"""The fill's options, each declared once.

A :class:`FillOptions` field carries its command-line flags and help (so ``tween
fill-local``, ``tween fill`` and ``tween submit`` offer the same options, built by
:func:`with_fill_options`) and, for the options that name files, its path role: the farm
makes those absolute in its payload and checks them against the shot roots
(:data:`PATH_FIELDS`), so a new path option cannot escape the check.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, fields

import numpy as np

from pipeline.errors import TweenError
from pipeline.options import option, with_options
from pipeline.usd.keys import parse_keys, parse_range


def _opt(default, *flags: str, help: str, path: str | None = None):
    """A FillOptions field: its default, CLI flags, help, and path role ("dir", "file")."""
    return option(default, *flags, help=help, path=path)


@dataclass
class FillOptions:
    """The options of a fill, declared once: each field's flags and help make the CLI
    options of ``fill-local`` and the farm's ``fill`` and ``submit``
    (:func:`with_fill_options`), its ``path`` role puts it in the shot-root check and makes
    it absolute in the farm payload (:data:`PATH_FIELDS`). JSON-serialisable (``asdict``):
    it travels in Celery messages."""

    keys: str | None = _opt(
        None, "--keys", help="Key time codes: '1001,1012,1030' or '1001-1100x8' (default: the shot's keys)."
    )
    range: str | None = _opt(
        None, "--range", help="Time codes to fill, e.g. 1010-1050 (default: the key span)."
    )
    takes: int = _opt(1, "--takes", help="Takes (variations) per shot, 1 to 64.")
    seed: int = _opt(0, "--seed", help="Seed of the first take (take k uses seed + k).")
    model: str = _opt(
        "default",
        "--model",
        help="default (a stored rig model when one fits the character, else the human model), interp, "
        "spline, or a model name/folder (a rig model is then used for every character that fits it).",
    )
    out_dir: str | None = _opt(
        None, "--out-dir", "--out", help="Folder for the layers (default: beside each shot).", path="dir"
    )
    fmt: str = _opt("usda", "--format", help="Fill layer format: usda or usdc.")
    mapping: str | None = _opt(None, "--mapping", help="JSON joint-mapping override file.", path="file")
    review_layer: str | None = _opt(
        None,
        "--review-layer",
        help="Add the fill to this root layer instead of a new review layer.",
        path="file",
    )
    dna: str | None = _opt(
        None,
        "--dna",
        help="Motion DNA: a reference take (USD or BVH) whose poses steer the fill.",
        path="file",
    )
    dna_poses: int = _opt(4, "--dna-poses", help="Representative poses taken from --dna, 1 to 8.")
    library: str | None = _opt(
        None,
        "--library",
        help="A studio's motion library (`tween library build`): each gap of a human character is "
        "filled from its best-matching takes, fitted to the keys, where they match; the spline elsewhere; "
        "the network --model names (the default's, or a studio's fine-tune) is probed beside it. "
        "Default: the studio's library, TWEEN_LIBRARY (`tween fill` and `submit`: the farm's `library` "
        "setting, the variable or the farm config's), else none; none for --model spline or interp.",
        path="dir",
    )
    strict: bool = _opt(
        False,
        "--strict",
        help="Refuse a shot whose sublayers, references or payloads are missing (default: a warning "
        "line for each, recorded in the fill's JSON).",
    )
    trust: str = _opt(
        "auto",
        "--trust",
        help="How far the human model is trusted against the spline through the keys (Catmull-Rom "
        "tangents where keys are dense, clamped where sparse): auto (decided per character from the "
        "shot's own keys, recorded in the layer), model, or spline.",
    )

    def check(self) -> FillOptions:
        """Raises TweenError (one line naming the option) unless every field is valid;
        cheap (reads no file, loads no model), so it runs before anything else."""
        check_fill_options(self)
        return self


#: Takes per shot: each is a full fill (and a variant of the layer), so a typo such as
#: ``--takes 10000`` is refused rather than queued.
MAX_TAKES = 64
#: The seed of take k is ``seed + k``; it is stored in the layer's ``tween:seed`` (a USD
#: int, 32 bits), so every take's seed is within 0 .. 2**31 - 1.
MAX_SEED = 2**31 - 1
FORMATS = ("usda", "usdc")
#: pipeline.infer.trust.TRUST_MODES, not imported for the check (that module pulls in scipy).
TRUST_MODES = ("auto", "model", "spline")
#: ``--model`` values that name no network: a library fill refuses them.
NOT_NETWORKS = ("interp", "interpolation", "spline")
#: pipeline.infer.dna_poses.MAX_POSES, not imported for the check (that module pulls in scipy).
MAX_DNA_POSES = 8


def _is_int(v) -> bool:
    return isinstance(v, int | np.integer) and not isinstance(v, bool)


def _opt_path(opt: str, v) -> None:
    if v is None:
        return
    if not isinstance(v, str | os.PathLike) or not str(v).strip() or "\0" in str(v):
        raise TweenError(f"{opt} {v!r}: expected a file or folder path")


def check_fill_options(opts: FillOptions) -> None:
    """Validates every field of ``opts``; the messages name the command-line options."""

    if not _is_int(opts.takes) or not 1 <= opts.takes <= MAX_TAKES:
        raise TweenError(f"--takes {opts.takes!r}: must be a whole number from 1 to {MAX_TAKES}")
    if not _is_int(opts.seed) or opts.seed < 0:
        raise TweenError(f"--seed {opts.seed!r}: must be a whole number, 0 or more")
    if opts.seed + opts.takes - 1 > MAX_SEED:
        last = f" (take {opts.takes - 1} uses seed {opts.seed + opts.takes - 1})" if opts.takes > 1 else ""
        raise TweenError(
            f"--seed {opts.seed}: every take's seed (seed + take) must be at most 2**31-1 = {MAX_SEED}{last}"
        )
    if not isinstance(opts.strict, bool):
        raise TweenError(f"--strict {opts.strict!r}: must be true or false")
    if opts.fmt not in FORMATS:
        raise TweenError(f"--format {opts.fmt!r}: must be usda or usdc")
    if opts.trust not in TRUST_MODES:
        raise TweenError(f"--trust {opts.trust!r}: must be one of {', '.join(TRUST_MODES)}")
    if not _is_int(opts.dna_poses) or not 1 <= opts.dna_poses <= MAX_DNA_POSES:
        raise TweenError(f"--dna-poses {opts.dna_poses!r}: must be a whole number from 1 to {MAX_DNA_POSES}")
    if not isinstance(opts.model, str) or not opts.model.strip():
        raise TweenError(f"--model {opts.model!r}: expected default, interp, or a model name or folder")
    if opts.library and opts.model in NOT_NETWORKS:  # nothing to probe beside the library
        raise TweenError(
            f"--library {opts.library}: fills from the library with a network probed beside it; "
            f"--model {opts.model} is no network (drop it, or name a network such as a studio's fine-tune)"
        )
    if opts.keys is not None:
        if not isinstance(opts.keys, str):
            raise TweenError(f"--keys {opts.keys!r}: expected key time codes, e.g. 1001,1012,1030")
        times = parse_keys(opts.keys)
        if not np.isfinite(times).all():
            raise TweenError(f"--keys {opts.keys!r}: key time codes must be finite numbers")
    if opts.range is not None:
        if not isinstance(opts.range, str):
            raise TweenError(f"--range {opts.range!r}: expected START-END, e.g. 1010-1050")
        if not all(math.isfinite(t) for t in parse_range(opts.range)):
            raise TweenError(f"--range {opts.range!r}: time codes must be finite numbers")
    for opt, v in (("--out-dir", opts.out_dir), ("--mapping", opts.mapping), ("--review-layer", opts.review_layer),
                   ("--dna", opts.dna), ("--library", opts.library)):  # fmt: skip
        _opt_path(opt, v)


#: The fields that name a path (``out_dir`` a folder, the others files).
PATH_FIELDS: dict[str, str] = {
    f.name: f.metadata["path"] for f in fields(FillOptions) if f.metadata.get("path")
}


#: The typer command with every FillOptions field as an option (``opts: FillOptions``).
with_fill_options = with_options(FillOptions)
