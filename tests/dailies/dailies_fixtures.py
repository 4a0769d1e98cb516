"""Builders the dailies tests share (imported by name: every test folder's conftest is a
module called ``conftest``, so these cannot live in one)."""

from __future__ import annotations

from pathlib import Path

from usd_fixtures import bandai_shot

TOKEN = "t" * 40


def filled_shot(folder: Path, name: str, takes: int = 2, render: bool = True, frames: int = 31) -> dict:
    """``folder/name.usda`` filled (interpolation, ``takes`` takes) and, with ``render``, its
    takes rendered where the farm puts them (``<fills>/review``)."""
    from pipeline.fill.api import FillOptions, fill_shot

    folder.mkdir(parents=True, exist_ok=True)
    shot = bandai_shot(folder / f"{name}.usda", frames=frames)
    r = fill_shot(str(shot), FillOptions(model="interp", takes=takes))
    if render:
        from render.review import render_review

        for t in range(takes) if takes > 1 else [None]:
            render_review(r["review"], str(folder / "review"), take=t, size=(96, 64), write_frames=False)
    return {"shot": shot, **r}


def client_for(roots, token: str = TOKEN, login: bool = True, tracker=None, mapping=None):
    from fastapi.testclient import TestClient

    from dailies.app import create_app
    from dailies.auth import Login

    auth = Login(token)
    c = TestClient(create_app(roots, auth, tracker, mapping))
    c.login = auth
    if login:
        assert c.get(f"/?token={token}").status_code == 200
    return c
