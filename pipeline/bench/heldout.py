"""The protocol's task on a source the model never saw: the CMU takes of ``../shared/data/cmu_iclone``.

Windows are cut as PROTOCOL.md cuts the eval clips (65 frames every 40) from the takes
retargeted onto the model skeleton by the product's own USD path (``long_gaps``), then
normalised the same way. Not the protocol: another actor set, another capture and a rig
mapped onto the model's, which is what a studio's shots look like to the model.
"""

from __future__ import annotations

import errno
import sys

import numpy as np

from pipeline.atomic import replacing
from pipeline.data.cache import cache_dir
from pipeline.data.protocol import TEST_STRIDE, TEST_WINDOW, normalize_windows, windows_of
from pipeline.data.split import shared_data_dir
from pipeline.errors import TweenError

VERSION = 1
SOURCES = ("eval", "cmu")  # the protocol's eval split; the CMU takes


def parse_source(source: str) -> tuple[str, tuple[int, ...] | None]:
    """``"cmu"`` -> ("cmu", None); ``"cmu:5,6,7"`` -> ("cmu", (5, 6, 7)): the CMU subjects to
    take (a studio fine-tuned on subjects 1-3 is measured on 5-7); other sources as they are."""
    name, colon, rest = source.partition(":")
    if name not in SOURCES:
        raise TweenError(f"source {source!r}: expected one of {', '.join(SOURCES)} (cmu:5,6,7: subjects)")
    if not colon:
        return source, None
    if name != "cmu":
        raise TweenError(f"source {source!r}: only cmu takes a subject list (cmu:5,6,7)")
    try:
        subjects = tuple(sorted({int(x) for x in rest.split(",") if x.strip()}))
    except ValueError:
        raise TweenError(f"source {source!r}: subjects must be numbers (cmu:5,6,7)") from None
    if not subjects:
        raise TweenError(f"source {source!r}: no subjects listed")
    return name, subjects


def posture_degrees(source: str) -> float | None:
    """N for a source ``postureN`` (eval windows with posture offsets up to N degrees), None for
    any other source (or a ``posture`` with no number after it)."""
    if not source.startswith("posture"):
        return None
    try:
        return float(source[len("posture") :])
    except ValueError:
        return None


def cmu_files(subjects: tuple[int, ...] | None = None) -> list:
    """The CMU takes (``NNN_TT.bvh.gz``), of the given subjects only when given."""
    folder = shared_data_dir() / "cmu_iclone"
    files = sorted(folder.glob("*.bvh.gz"))
    if subjects is not None:
        files = [f for f in files if f.name[:3].isdigit() and int(f.name[:3]) in subjects]
    if not files:
        which = "" if subjects is None else f" of subjects {', '.join(map(str, subjects))}"
        # The folder named, so that every entry point says it in one line (pipeline.command).
        raise FileNotFoundError(errno.ENOENT, f"no CMU takes{which} there", str(folder))
    return files


def cmu_windows(
    subjects: tuple[int, ...] | None = None, limit: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(rotations (N, 65, J, 4), roots (N, 65, 3)), cached after the first call; ``subjects``:
    those CMU subjects' takes only; ``limit``: the first ``limit`` of those takes only."""
    files = cmu_files(subjects)[: limit or None]
    tag = "" if subjects is None else "-s" + "".join(map(str, subjects))
    cache = cache_dir() / f"cmu-windows-v{VERSION}-{len(files)}{tag}.npz"
    if cache.exists():
        d = np.load(cache)
        return d["rots"], d["roots"]
    from pipeline.bench.long_gaps import cmu_on_model_skeleton

    def takes():
        for i, f in enumerate(files):
            print(f"retargeting CMU take {i + 1}/{len(files)}: {f.name}", file=sys.stderr)
            m = cmu_on_model_skeleton(f)
            yield m.rotations, m.root_positions

    rots, roots = windows_of(takes(), TEST_WINDOW, TEST_STRIDE)
    rots, roots = normalize_windows(rots.astype(np.float32), roots.astype(np.float32))
    with replacing(cache, suffix=".npz") as tmp:  # removed when interrupted
        np.savez(tmp, rots=rots, roots=roots)
    return rots, roots
