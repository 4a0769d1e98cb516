"""Fixtures shared by the farm tests."""

from __future__ import annotations

import os

import pytest
from redis_server import configure_app


@pytest.fixture
def embedded_app(tmp_path):
    """The fill app on an embedded (SQLite) result store under ``tmp_path``."""
    from workers.app import app
    from workers.settings import load_settings

    old = app.conf.tween
    configure_app(app, load_settings({"TWEEN_FARM_CONFIG": os.devnull, "TWEEN_CACHE": str(tmp_path)}))
    try:
        yield app
    finally:
        configure_app(app, old)
