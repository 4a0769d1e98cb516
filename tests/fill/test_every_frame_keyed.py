"""A shot sampled on every frame with no keys named (a DCC's export: Blender's samples every
frame): every frame is a key, so nothing is in-betweened. The fill wrote a layer of the keys
alone and said nothing of it; now one warning says so and how to name the keys."""

from __future__ import annotations

import shutil
from pathlib import Path

from usd_fixtures import tween

BLENDER = Path(__file__).resolve().parents[1] / "fixtures" / "blender" / "ik_roots.usda"


def test_every_frame_a_key_is_said_and_keys_named_are_not(tmp_path, monkeypatch, capsys):
    shot = tmp_path / "rig.usda"
    shutil.copy(BLENDER, shot)
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--model", "interp")
    assert rc == 0, err
    said = [ln for ln in err.splitlines() if "every frame is a key" in ln]
    assert len(said) == 1 and "--keys 1-61x10" in said[0] and str(shot) in said[0], err
    rc, err = tween(monkeypatch, capsys, "fill-local", shot, "--model", "interp", "--keys", "1-61x10")
    assert rc == 0 and "every frame is a key" not in err, err
