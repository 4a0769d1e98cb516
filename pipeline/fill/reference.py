"""A reference take on the model skeleton: the source of a motion DNA (``tween fill --dna``).

A USD file's first animated character (the same reading, joint mapping and retargeting as
a shot's), or a BVH file, converted to a USD take first so that it goes the same way.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from pipeline.adapt.mapping import map_joints
from pipeline.data.skeletons import bandai_skeleton
from pipeline.errors import ShotError
from pipeline.motion.clip import Motion


def _usd_take(path: Path, fps: float, name: str) -> Motion:
    from pipeline.adapt.retarget import Retarget
    from pipeline.usd.read import anim_values, read_shot, to_skeleton_order

    shot = read_shot(path)
    c = shot.characters[0]
    rt = Retarget(c, map_joints(c.joints, c.parents), shot.up_axis, shot.meters_per_unit)
    times = np.arange(shot.start, shot.end + 1e-6, shot.tcps / fps)
    if len(times) < 2:
        raise ShotError(path, "the reference take has fewer than two frames")
    rot, tr = to_skeleton_order(c, *anim_values(shot.stage, c, times)[:2])
    q, root = rt.to_model(rot, tr)
    return Motion(bandai_skeleton(), q, root, fps, name).continuous()


def reference_take(path: str | Path, fps: float = 30.0) -> Motion:
    """The take in ``path`` (.usd/.usda/.usdc, or .bvh/.bvh.gz) on the model skeleton."""
    path = Path(path)
    if not path.is_file():
        raise ShotError(path, "no such reference file")
    if path.name.endswith((".bvh", ".bvh.gz")):
        from pipeline.motion.bvh import read_bvh
        from pipeline.usd.convert import write_shot

        try:
            m = read_bvh(path)
        except (ValueError, IndexError, OSError) as e:
            raise ShotError(path, f"cannot read the BVH: {e}") from None
        with tempfile.TemporaryDirectory() as tmp:
            return _usd_take(write_shot(m, Path(tmp) / "take.usda", start=0, fps=fps), fps, m.name)
    return _usd_take(path, fps, path.name)
