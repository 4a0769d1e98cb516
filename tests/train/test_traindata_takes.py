"""`tween train --data FOLDER`: every take is checked (kind, size, first bytes) before any is
read, so a studio's broken take is one line naming it in seconds, not after minutes of
reading the good ones; whatever is named like a take and is not one is refused alike (a
pipe was skipped unsaid, a link loop skipped with a warning, an empty file refused last)."""

from __future__ import annotations

import os
import re
import shutil
import time
from pathlib import Path

import pytest

pytest.importorskip("torch")

from cli_contract import failed, refused  # noqa: E402
from pipe_guard import within  # noqa: E402

from pipeline.errors import TweenError  # noqa: E402

RUN = ["--steps", "4", "--path-steps", "0", "--batch", "2", "--lengths", "64", "--adv-start", "-1"]
WHY = "--data reads every take in its folder: mend or remove this one, or leave it out with --data-include"


def _many_takes(data_dir: Path, folder: Path) -> Path:
    """A folder of every CMU take (links to the shared files: regular takes all) and a Bandai one."""
    folder.mkdir()
    takes = sorted((data_dir / "cmu_iclone").glob("*.bvh.gz"))
    assert len(takes) > 40
    for t in takes:
        (folder / t.name).symlink_to(t)
    shutil.copy(
        data_dir / "bandai_namco" / "dataset-2" / "dataset-2_walk_active_002.bvh.gz", folder / "b.bvh.gz"
    )
    return folder


@pytest.fixture
def no_take_read(monkeypatch):
    """Every take read (mapped, retargeted) fails the test: a refusal must come first."""

    def read(path):
        pytest.fail(f"{path} was read before the broken take was refused")

    monkeypatch.setattr("pipeline.usd.take.studio_take", read)


def _bad_takes(folder: Path) -> dict:
    """Each odd file, made last in sort order, and the phrase its refusal gives."""

    def fifo(p):
        os.mkfifo(p)

    return {
        "zzz.bvh": (fifo, "not a regular file (a pipe, socket or device), not a take file"),
        "zzz_empty.bvh": (lambda p: p.write_bytes(b""), "an empty file, not a take"),
        "zzz_noise.bvh": (lambda p: p.write_bytes(os.urandom(3000)), "not a BVH take (it does not start with HIERARCHY)"),
        "zzz_noise.usdc": (lambda p: p.write_bytes(os.urandom(3000)), "not a USD take (it does not start as USD text"),
        "zzz_noise.bvh.gz": (lambda p: p.write_bytes(b"HIERARCHY\n"), "named .gz, but not gzip data"),
    }  # fmt: skip


def test_an_odd_file_among_many_takes_is_refused_at_once_before_any_take_is_read(
    data_dir, tmp_path, capsys, monkeypatch, no_take_read
):
    monkeypatch.setenv("TWEEN_CACHE", str(tmp_path / "cache"))
    folder = _many_takes(data_dir, tmp_path / "takes")
    out = tmp_path / "run"
    for name, (make, why) in _bad_takes(folder).items():
        bad = folder / "sub" / name  # in a subfolder too: the walk is recursive
        bad.parent.mkdir(exist_ok=True)
        make(bad)
        t0 = time.monotonic()
        line = within(
            lambda: refused(["train", "--out", out, *RUN, "--data", folder], capsys, tmp_path), [bad]
        )
        took = time.monotonic() - t0
        assert line.startswith(f"tween: error: {bad}: {why}") and line.endswith(WHY), line
        # no_take_read fails the test if a take is read first; the bound is only a backstop
        # (reading the 62 takes takes about a minute).
        assert took < 20.0, f"{name}: refused after {took:.1f} s"
        (bad.rmdir if bad.is_dir() else bad.unlink)()
    assert not out.exists()


def test_links_that_lead_nowhere_are_refused_as_well(data_dir, tmp_path, capsys, monkeypatch, no_take_read):
    """A link loop and a link to nothing are refused as the rest, not skipped (the takes
    listing's warning about them may come first; the error line is the last and only one)."""
    monkeypatch.setenv("TWEEN_CACHE", str(tmp_path / "cache"))
    folder = _many_takes(data_dir, tmp_path / "takes")
    cases = {"zzz_loop.bvh": ("zzz_loop.bvh", "a link loop (it leads back to itself), not a take file"),
             "zzz_gone.usd": (str(tmp_path / "nowhere.usd"), "a link to nothing")}  # fmt: skip
    for name, (target, why) in cases.items():
        (folder / name).symlink_to(target)
        t0 = time.monotonic()
        line = failed(["train", "--out", tmp_path / "run", *RUN, "--data", folder], capsys)
        assert line.startswith(f"tween: error: {folder / name}: {why}; ") and line.endswith(WHY), line
        assert time.monotonic() - t0 < 20.0  # no_take_read is the check; this a backstop
        (folder / name).unlink()
    assert not (tmp_path / "run").exists()


def test_the_path_predictor_checks_the_takes_before_it_reads_one(
    data_dir, bandai_clip, tmp_path, monkeypatch
):
    """The path predictor (a run's first reader of the takes) refuses as the generator does;
    a take that passes the check and fails to read is still one line naming it."""
    from pipeline.train.generator_training import TrainConfig, training_clips
    from pipeline.train.path_training import PathTrainConfig, train_path
    from pipeline.usd import take

    monkeypatch.setenv("TWEEN_CACHE", str(tmp_path / "cache"))
    folder = _many_takes(data_dir, tmp_path / "takes")
    (folder / "zzz.usda").write_bytes(b"")
    reader = take.studio_take
    monkeypatch.setattr(take, "studio_take", lambda p: pytest.fail(f"{p} read before the refusal"))
    want = f"{folder / 'zzz.usda'}: an empty file, not a take; {WHY}"
    with pytest.raises(TweenError) as e:
        train_path(PathTrainConfig(steps=4, batch=2, data=str(folder)), tmp_path / "run")
    assert str(e.value) == want and not (tmp_path / "run").exists()
    # --limit-clips trains on the first takes only, but the folder is checked whole (an
    # export's pose bank reads every take).
    with pytest.raises(TweenError) as e:
        training_clips(TrainConfig(data=str(folder), limit_clips=1))
    assert str(e.value) == want
    monkeypatch.setattr(take, "studio_take", reader)
    small = tmp_path / "small"
    small.mkdir()
    shutil.copy(bandai_clip, small / bandai_clip.name)
    (small / "zzz.bvh").write_text("HIERARCHY\nROOT Hips\n{\n")  # starts as a BVH, is cut short
    with pytest.raises(TweenError, match=rf"^{re.escape(str(small / 'zzz.bvh'))}:\d+: .*truncated"):
        train_path(PathTrainConfig(steps=4, batch=2, data=str(small)), tmp_path / "run")


def test_a_folder_named_like_a_take_is_looked_into_not_refused(tmp_path):
    """``archive.bvh/`` holding takes: the takes listing walks into it, and so does the check
    (it was refused as "a folder named like a take")."""
    from pipeline.train.corpus import check_takes

    inner = tmp_path / "takes" / "archive.bvh"
    inner.mkdir(parents=True)
    take = inner / "walk.bvh"
    take.write_text("HIERARCHY\nROOT Hips\n{\n}\n")
    assert check_takes(tmp_path / "takes") == [take]
