"""A farm job whose output folder stopped taking writes after it was submitted (a read-only
mount, permissions changed, the folder published): the stage fails in one line naming that
folder, as the user gave it, and what to do; never the job's temp inside it (``.tween-work``)
in a raw ``[Errno 30]`` / ``[Errno 13]`` line. The stages run in this process (Celery's
``apply``) on an embedded result store under ``tmp_path``."""

from __future__ import annotations

import errno
import os
import shutil
import uuid

import pytest
from redis_server import REPO, configure_app


@pytest.fixture
def embedded_app(tmp_path):
    from workers.app import app
    from workers.settings import load_settings

    old = app.conf.tween
    env = {
        "TWEEN_FARM_CONFIG": os.devnull,
        "TWEEN_CACHE": str(tmp_path / "cache"),
        "TWEEN_SHOT_ROOTS": str(tmp_path),
    }
    configure_app(app, load_settings(env))
    try:
        yield app
    finally:
        configure_app(app, old)


def _take(tmp_path, out_dir: str | None):
    """A shot under ``tmp_path/shots``, its options and a job, as `tween submit` makes them."""
    from workers.jobs import make_opts, work_dir_for

    shot = tmp_path / "shots" / "sh010.usda"
    shot.parent.mkdir()
    shutil.copyfile(REPO / "examples" / "sh010_walk.usda", shot)
    opts = make_opts(model="interp", out_dir=out_dir)
    job_id = uuid.uuid4().hex
    job = {"id": job_id, "takes": 1, "render": False, "made_dirs": []}
    job["work_dir"] = work_dir_for(str(shot), opts, job_id)
    return str(shot), opts, job


@pytest.mark.parametrize(("err", "given"), [(errno.EROFS, True), (errno.EACCES, False)])
def test_a_folder_that_refuses_writes_is_named_not_the_temp(embedded_app, tmp_path, monkeypatch, err, given):
    """EROFS (a read-only mount) with --out-dir, EACCES (a folder this user may not write)
    beside the shot: both were "[Errno N] …: '<folder>/.tween-work'"."""
    from workers import tasks

    out = tmp_path / "out" if given else tmp_path / "shots"
    if given:
        out.mkdir()
    shot, opts, job = _take(tmp_path, str(out) if given else None)
    real = os.makedirs

    def refused(path, *a, **kw):  # what the folder's file system answers
        if str(path).startswith(str(out)):
            raise OSError(err, os.strerror(err), os.path.dirname(str(path)))
        return real(path, *a, **kw)

    monkeypatch.setattr(tasks.os, "makedirs", refused)
    r = tasks.fill_take.apply(args=(shot, opts, 0, job), task_id=f"{job['id']}.take0")
    assert r.status == "FAILURE"
    assert str(r.result) == (
        f"{shot}: output folder {out} cannot be written ({os.strerror(err)}); make it writable, or run the "
        "job again with another --out-dir DIR"
    )


def test_a_folder_made_read_only_after_submit_stays_untouched(embedded_app, tmp_path):
    """Read-only by its mode bits (published since the job was sent): refused as the client
    refuses it, even by a worker running as root, whom the file system lets write (it made
    the job's temp there and wrote the takes into it)."""
    from workers import tasks

    out = tmp_path / "out"
    out.mkdir()
    shot, opts, job = _take(tmp_path, str(out))
    out.chmod(0o555)
    try:
        r = tasks.fill_take.apply(args=(shot, opts, 0, job), task_id=f"{job['id']}.take0")
    finally:
        out.chmod(0o755)
    assert r.status == "FAILURE"
    assert str(r.result) == f"{shot}: output folder {out} is read-only (give another with --out-dir DIR)"
    assert list(out.iterdir()) == []


def test_a_shot_that_cannot_be_read_is_not_called_an_unwritable_folder(tmp_path):
    """A permission error on a file the job reads there (the shot) is said as it is."""
    from workers.tasks import _unwritable

    shot, out = str(tmp_path / "sh010.usda"), str(tmp_path)
    assert _unwritable(PermissionError(errno.EACCES, "Permission denied", shot), shot, out) is None
    made = PermissionError(errno.EACCES, "Permission denied", os.path.join(out, ".tween-work"))
    assert _unwritable(made, shot, out) is not None
