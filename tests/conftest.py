"""Shared fixtures: where the real data lives, and a per-session cache folder."""

import os
import sys
from pathlib import Path

import pytest

from pipeline.data.split import shared_data_dir

# The tests mirror the package tree (tests/usd/, tests/fill/, …); the shared fixture modules
# (usd_fixtures, render_fixtures, …) stay here, beside this file.
# Some test modules reuse another's builders (test_farm_rig uses test_rig_fill's): every
# folder of the tree is on the path too (test module names are unique across it).
_HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(_HERE)] + sorted(
    str(d) for d in _HERE.iterdir() if d.is_dir() and not d.name.startswith((".", "_"))
)

DATA = shared_data_dir()


def pytest_configure(config):
    # Keep cache writes (parsed clips, statistics) out of the user's home during tests
    # unless a cache is configured; reuse one across the session.
    os.environ.setdefault("TWEEN_CACHE", str(Path(__file__).resolve().parents[1] / ".cache" / "tests"))
    # A studio's library in the shell (every fill's default, fill-local's too) would change
    # every default-model fill here; the library tests set it themselves.
    os.environ.pop("TWEEN_LIBRARY", None)


def pytest_collection_finish(session):
    # The Kitsu tests' zou venv (minutes of pip install, mostly network) is made while the
    # tests before them run, when they are selected and there is a PostgreSQL to serve it.
    if any(item.path.name == "test_kitsu.py" for item in session.items):
        from kitsu_server import PG_BIN, build_zou_venv

        if (PG_BIN / "initdb").exists():
            build_zou_venv()


@pytest.fixture(scope="session")
def data_dir() -> Path:
    if not DATA.is_dir():
        pytest.fail(f"shared data not found at {DATA} (set TWEEN_DATA)")
    return DATA


@pytest.fixture(scope="session")
def bandai_clip(data_dir) -> Path:
    return data_dir / "bandai_namco" / "dataset-2" / "dataset-2_walk_active_002.bvh.gz"
