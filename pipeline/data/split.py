"""The fixed train/eval split of ../shared/data/bandai_namco (see its README and PROTOCOL.md)."""

from __future__ import annotations

import os
import re
from pathlib import Path

from pipeline.errors import TweenError

_TAKE = re.compile(r"_(\d+)\.bvh(\.gz)?$")


def shared_data_dir() -> Path:
    """``$TWEEN_DATA`` or ``../shared/data`` beside the checkout."""
    env = os.environ.get("TWEEN_DATA")
    if env:
        return Path(env)
    here = Path(__file__).resolve()
    for parent in here.parents:
        cand = parent.parent / "shared" / "data"
        if cand.is_dir():
            return cand
    return Path("../shared/data").resolve()


def bandai_dir() -> Path:
    return shared_data_dir() / "bandai_namco"


def is_eval(path: str | Path) -> bool:
    """eval = dataset-2 clips whose take number % 5 == 2."""
    name = Path(path).name
    m = _TAKE.search(name)
    return name.startswith("dataset-2_") and m is not None and int(m.group(1)) % 5 == 2


def list_clips(split: str, root: Path | None = None) -> list[Path]:
    """Sorted clip paths of ``split`` ("train" or "eval")."""
    if split not in ("train", "eval"):
        raise ValueError(f"split must be train or eval, not {split!r}")
    root = root or bandai_dir()
    files = sorted(p for p in root.glob("dataset-*/*.bvh*") if p.name.endswith((".bvh", ".bvh.gz")))
    if not files:  # a user's setting, not a bug: one line (it was an internal error, exit 1)
        where = (
            f"TWEEN_DATA {os.environ['TWEEN_DATA']}" if os.environ.get("TWEEN_DATA") else "the shared data"
        )
        raise TweenError(
            f"{root}: no Bandai Namco clips (dataset-*/*.bvh[.gz]) there; {where} is not the data folder"
        )
    return [p for p in files if is_eval(p) == (split == "eval")]
