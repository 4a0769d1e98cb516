"""pipeline.staging without torch: what a staged model folder refuses before anything is written."""

from __future__ import annotations

import pytest

from pipeline.errors import TweenError
from pipeline.staging import StagedFolder


def test_the_folder_you_are_in_is_refused(tmp_path, monkeypatch):
    """Before: ``--out .`` (empty) or ``--out . --force`` (a model) renamed the current folder
    away under the user's shell, which was left in the old one."""
    dest = tmp_path / "m"
    dest.mkdir()
    monkeypatch.chdir(dest)
    for given, force in ((".", True), (str(dest), True), ("../m", False), (".", False)):
        with pytest.raises(TweenError, match="is the folder you are in"):
            StagedFolder(given, force=force)
    assert dest.is_dir() and not any(tmp_path.glob(".m*"))
    monkeypatch.chdir(tmp_path)  # from outside it, the same folder is fine
    assert StagedFolder(dest, force=True).work.parent == tmp_path
