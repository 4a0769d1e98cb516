"""Filled shots with their farm-style review renders, and a logged-in client of the page."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from dailies_fixtures import TOKEN, client_for, filled_shot  # noqa: F401


@pytest.fixture(autouse=True)
def fresh_scans(monkeypatch):
    """Every list walks the roots again (tests add fills behind the server's back)."""
    monkeypatch.setattr("dailies.shots.SCAN_AGE", 0.0)


@pytest.fixture(scope="session")
def rendered_source(tmp_path_factory) -> Path:
    """One shot, two takes rendered: built once, copied per test (approvals change it)."""
    root = tmp_path_factory.mktemp("dailies-src")
    filled_shot(root / "seq01", "sh010")
    return root


@pytest.fixture
def roots(rendered_source, tmp_path) -> list[Path]:
    root = tmp_path / "shots"
    shutil.copytree(rendered_source, root, symlinks=True)
    return [root]


@pytest.fixture
def client(roots):
    return client_for(roots)
