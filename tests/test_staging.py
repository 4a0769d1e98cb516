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


def _dead_pid() -> int:
    import subprocess
    import sys

    p = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    return int(p.stdout)


def test_a_swap_killed_halfway_is_put_back_by_the_next_run(tmp_path, capsys):
    """A run killed inside commit left the studio's model (and its notes) in a hidden
    .<name>.old-PID: between the two renames the model folder was gone."""
    dest = tmp_path / "model"
    old = tmp_path / f".model.old-{_dead_pid()}"
    old.mkdir()
    (old / "model.json").write_text("{}")
    (old / "notes.txt").write_text("the studio's")
    # Killed between moving the old model aside and the new one in: it goes back.
    with pytest.raises(TweenError, match="holds a finished model"):
        StagedFolder(dest)
    assert (dest / "model.json").is_file() and (dest / "notes.txt").read_text() == "the studio's"
    assert not old.exists() and "put back the model a killed run had moved aside" in capsys.readouterr().err
    # Killed after the new model was in place: the kept files join it, the old model goes.
    dest.rename(old)
    new = tmp_path / "new"
    new.mkdir()
    (new / "model.json").write_text('{"new": 1}')
    new.rename(dest)
    StagedFolder(dest, force=True)
    assert (dest / "notes.txt").read_text() == "the studio's" and (
        dest / "model.json"
    ).read_text() == '{"new": 1}'
    assert not old.exists() and "kept files moved back" in capsys.readouterr().err
    # A file of the same name on both sides is never removed: said, and left where it is.
    old.mkdir()
    (old / "notes.txt").write_text("older notes")
    StagedFolder(dest, force=True)
    assert (old / "notes.txt").read_text() == "older notes" and "compare them" in capsys.readouterr().err


def test_a_swap_whose_process_still_runs_is_left_to_it(tmp_path):
    import os

    old = tmp_path / f".model.old-{os.getpid()}"
    old.mkdir()
    (old / "model.json").write_text("{}")
    StagedFolder(tmp_path / "model")
    assert old.is_dir() and not (tmp_path / "model").exists()
