"""`tween train-rig --out` never mixes a model with a studio's own files, never replaces
those, names a damaged checkpoint and a thread count it cannot resume with, and refuses a
read-only folder even for root (pipeline.staging, pipeline.rig.train)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("torch")

from cli_contract import refused, succeeded  # noqa: E402
from test_rig_core import walk  # noqa: E402

from pipeline.staging import StagedFolder  # noqa: E402

TINY = ["--schedule", "tiny", "--iters", "1"]


@pytest.fixture
def clip(tmp_path, monkeypatch) -> Path:
    """A 48-frame clip .npz (the shortest the tiny pyramid takes: seconds to train)."""
    from pipeline.rig.source import save_npz

    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    path = tmp_path / "c.npz"
    save_npz(walk(48), path)
    return path


def _files(folder: Path) -> dict:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_a_folder_of_other_files_is_refused_and_an_empty_one_used(tmp_path, clip, capsys, monkeypatch):
    """Before: a non-empty folder without rig.json was trained into directly, overwriting the
    user's MODEL_CARD.md and mixing level files and checkpoints with their notes."""
    shots = tmp_path / "shots"
    shots.mkdir()
    (shots / "notes.txt").write_text("the user's notes")
    (shots / "MODEL_CARD.md").write_text("the user's own card")
    line = refused(["train-rig", clip, "--out", shots, *TINY], capsys, tmp_path)
    assert line.startswith(f"tween: error: {shots}: --out is not empty and not a rig model folder"), line
    monkeypatch.chdir(shots)
    line = refused(["train-rig", clip, "--out", ".", *TINY], capsys, tmp_path)
    assert "not empty and not a rig model folder" in line
    monkeypatch.chdir(tmp_path)
    empty = tmp_path / "empty"
    empty.mkdir()
    succeeded(["train-rig", "c.npz", "--out", "empty", *TINY], capsys)  # both relative
    assert (empty / "rig.json").is_file() and (empty / "level_1.onnx").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.npz", "empty", "shots"]  # no .partial left
    # The model card names the folder the model is in, not the one it was trained in.
    card = (empty / "MODEL_CARD.md").read_text()
    assert 'RigInbetweener("empty")' in card and ".partial" not in card
    # The clip is recorded where it is, not relative to where the training ran.
    assert json.loads((empty / "rig.json").read_text())["source"]["path"] == str(clip)


def test_force_replaces_only_the_models_own_files(tmp_path, clip, capsys):
    """Before: --force removed everything in the old folder, the user's notes and renders too."""
    out = tmp_path / "m"
    succeeded(["train-rig", clip, "--out", out, *TINY], capsys)
    (out / "notes.txt").write_text("shot notes")
    (out / "renders").mkdir()
    (out / "renders" / "a.png").write_bytes(b"png")
    (out / "level_9.onnx").write_bytes(b"a level of an older model")
    old = (out / "rig.json").read_text()
    succeeded(["train-rig", clip, "--out", out, "--force", "--seed", "1", *TINY], capsys)
    assert (out / "rig.json").read_text() != old
    assert (out / "notes.txt").read_text() == "shot notes" and (
        out / "renders" / "a.png"
    ).read_bytes() == b"png"
    assert not (out / "level_9.onnx").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.npz", "m"]  # no .partial, no .old


def test_staged_generator_model_keeps_other_files(tmp_path):
    """`tween export --force` swaps a generator model the same way: its listed files, its
    manifest and card go; a studio's HISTORY.md and bench folder stay."""
    dest = tmp_path / "model"
    dest.mkdir()
    (dest / "model.json").write_text(
        json.dumps({"files": {"generator": "generator.onnx", "path": "path.onnx"}})
    )
    for name in ("generator.onnx", "path.onnx", "MODEL_CARD.md", "HISTORY.md"):
        (dest / name).write_text(f"old {name}")
    (dest / "bench").mkdir()
    (dest / "bench" / "r.json").write_text("{}")
    stage = StagedFolder(dest, force=True)
    work = stage.make()
    manifest = json.dumps({"files": {"generator": "generator.onnx"}}).encode()
    (work / "model.json").write_bytes(manifest)
    (work / "generator.onnx").write_text("new")
    stage.commit()
    assert _files(dest) == {
        "HISTORY.md": b"old HISTORY.md",
        "bench/r.json": b"{}",
        "generator.onnx": b"new",
        "model.json": manifest,
    }
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model"]


@pytest.mark.parametrize(
    "damage",
    [lambda b: b[: len(b) // 2], lambda b: b"", lambda b: b"\x80\x04 junk"],
    ids=["cut", "empty", "junk"],
)
def test_a_damaged_checkpoint_is_one_line_naming_it(tmp_path, clip, capsys, damage):
    """Before: torch.load's error (an internal error) for a cut, empty or junk state.pt."""
    out = tmp_path / "m"
    succeeded(["train-rig", clip, "--out", out, "--no-export", *TINY], capsys)
    state = tmp_path / ".m.partial" / "checkpoints" / "state.pt"
    state.write_bytes(damage(state.read_bytes()))
    line = refused(["train-rig", clip, "--out", out, *TINY], capsys, tmp_path)
    assert line.startswith(f"tween: error: {state}: the training checkpoint is damaged"), line
    assert f"remove {state.parent} to start this training over" in line


def test_resuming_with_other_threads_is_refused(tmp_path, clip, capsys):
    """Before: accepted, and the card recorded the new count for weights made with the old."""
    out = tmp_path / "m"
    succeeded(["train-rig", clip, "--out", out, "--no-export", "--threads", "1", *TINY], capsys)
    line = refused(["train-rig", clip, "--out", out, "--threads", "2", *TINY], capsys, tmp_path)
    assert "this training ran with --threads 1; resume it with --threads 1" in line, line
    succeeded(["train-rig", clip, "--out", out, "--threads", "1", *TINY], capsys)
    assert json.loads((out / "rig.json").read_text())["training"]["threads"] == 1


def test_checkpoints_naming_a_file_is_named_as_the_option(tmp_path, clip, capsys):
    """Before: "c.npz: File exists", as if the clip were wrong."""
    line = refused(
        ["train-rig", clip, "--out", tmp_path / "m", "--checkpoints", clip, *TINY], capsys, tmp_path
    )
    assert line == f"tween: error: {clip}: --checkpoints names a file, not a folder"


def test_a_read_only_folder_is_refused_even_for_root(tmp_path, clip, capsys):
    """Before: root wrote into a folder of mode 555 (rig-extract and train-rig)."""
    ro = tmp_path / "ro"
    ro.mkdir()
    (ro / "m").mkdir()
    ro.chmod(0o555)
    try:
        for argv, option in (
            (["rig-extract", clip, ro / "x.npz"], "OUT"),
            (["train-rig", clip, "--out", ro / "new", *TINY], "--out"),
            (["train-rig", clip, "--out", ro / "m", *TINY], "--out"),
        ):
            line = refused(argv, capsys, tmp_path)
            assert f"{option} is in {ro}, which is read-only" in line, line
    finally:
        ro.chmod(0o755)
    published = tmp_path / "published"
    succeeded(["train-rig", clip, "--out", published, *TINY], capsys)
    published.chmod(0o555)
    try:
        line = refused(["train-rig", clip, "--out", published, "--force", *TINY], capsys, tmp_path)
        assert line == f"tween: error: {published}: --out is read-only; give a folder you can write"
    finally:
        published.chmod(0o755)
    assert (published / "rig.json").is_file()
