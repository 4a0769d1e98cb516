"""The protocol's task on a source the model never saw: the CMU takes of ``../shared/data/cmu_iclone``.

Windows are cut as PROTOCOL.md cuts the eval clips (65 frames every 40) from the takes
retargeted onto the model skeleton by the product's own USD path (``long_gaps``), then
normalised the same way. Not the protocol: another actor set, another capture and a rig
mapped onto the model's, which is what a studio's shots look like to the model.
"""

from __future__ import annotations

import sys

import numpy as np

from pipeline.data.cache import cache_dir
from pipeline.data.protocol import TEST_STRIDE, TEST_WINDOW, normalize_windows, windows_of
from pipeline.data.split import shared_data_dir

VERSION = 1


def cmu_windows() -> tuple[np.ndarray, np.ndarray]:
    """(rotations (N, 65, J, 4), roots (N, 65, 3)), cached after the first call."""
    files = sorted((shared_data_dir() / "cmu_iclone").glob("*.bvh.gz"))
    if not files:
        raise FileNotFoundError(f"no CMU takes under {shared_data_dir() / 'cmu_iclone'}")
    cache = cache_dir() / f"cmu-windows-v{VERSION}-{len(files)}.npz"
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
    tmp = cache.with_suffix(".tmp.npz")
    np.savez(tmp, rots=rots, roots=roots)
    tmp.replace(cache)
    return rots, roots
