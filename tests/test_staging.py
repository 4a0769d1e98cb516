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


@pytest.mark.parametrize("target", ["loop", "nothing"])
def test_an_out_that_is_a_link_leading_nowhere_is_refused_by_every_check(tmp_path, target):
    """Making the folder failed with "File exists" (library build: an internal error)."""
    from pipeline.bench.outputs import check_out_file, check_out_folder
    from pipeline.staging import refuse_read_only

    link = tmp_path / "out"
    if target == "loop":
        (tmp_path / "other").symlink_to(link)
        link.symlink_to(tmp_path / "other")
    else:
        link.symlink_to(tmp_path / "gone")
    for check in (refuse_read_only, StagedFolder):
        with pytest.raises(TweenError, match=r"out: --out is a symbolic link that leads nowhere"):
            check(link)
    for check, given in ((check_out_folder, link / "sub"), (check_out_file, link / "bench.json")):
        with pytest.raises(TweenError, match=r"out is a symbolic link that leads nowhere"):
            check(given)
