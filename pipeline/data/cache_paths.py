"""Where caches live: one rule, in a module light enough for every command's start-up."""

from __future__ import annotations

import os
from pathlib import Path


def cache_root(env=None) -> Path:
    """``$TWEEN_CACHE`` or ``~/.cache/usd-tween``: the one rule for where caches live (clip
    sets, statistics, the embedded farm's broker); ``env`` defaults to the process's."""
    env = os.environ if env is None else env
    # empty is unset, as for the farm's settings (it put the embedded farm in the working folder)
    return Path(env.get("TWEEN_CACHE") or Path.home() / ".cache" / "usd-tween")


def cache_dir() -> Path:
    """:func:`cache_root`, created."""
    d = cache_root()
    d.mkdir(parents=True, exist_ok=True)
    return d
