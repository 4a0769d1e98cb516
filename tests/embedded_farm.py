"""The environment of an embedded `tween fill` under test: its own cache (broker, results,
logs), no farm config, and optionally the slow fill and render of the farm tests loaded into
every process of the run (client, worker, pool processes) through a sitecustomize."""

from __future__ import annotations

import os
from pathlib import Path

from redis_server import REPO

SITE = """
import os, sys
_mods = os.environ.get("TWEEN_TEST_SLOW_MODULES")
if _mods:
    sys.path.insert(0, os.environ["TWEEN_TEST_DIR"])
    for _m in _mods.split(","):
        __import__(_m)
"""


def embedded_env(tmp_path: Path, slow: tuple[str, ...] = (), **extra) -> dict:
    site = tmp_path / "site"
    site.mkdir(exist_ok=True)
    (site / "sitecustomize.py").write_text(SITE)
    env = {k: v for k, v in os.environ.items() if not k.startswith("TWEEN_")}
    env.update(
        TWEEN_CACHE=str(tmp_path / "cache"),
        TWEEN_FARM_CONFIG=os.devnull,
        PYTHONPATH=os.pathsep.join([str(site), str(REPO)]),
        TWEEN_TEST_DIR=str(REPO / "tests"),
    )
    if slow:
        env["TWEEN_TEST_SLOW_MODULES"] = ",".join(slow)
    if "TWEEN_DATA" in os.environ:
        env["TWEEN_DATA"] = os.environ["TWEEN_DATA"]
    env.update({k: str(v) for k, v in extra.items()})
    return env


def worker_log(tmp_path: Path) -> str:
    logs = sorted((tmp_path / "cache" / "farm" / "logs").glob("*.log"))
    return "\n".join(p.read_text(errors="replace") for p in logs)
