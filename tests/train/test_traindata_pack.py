"""`tween train --data-pack PACK`: the path predictor trains on the pack's clips as the
generator does (it read the train split from ../shared), --data beside it is refused (the
pack won, unsaid), and a run decodes the pack once (the up-front check and the training
each decoded it). And `--init PIPE` says what it is, not "checkpoint not found"."""

from __future__ import annotations

import os

import numpy as np
import pytest

pytest.importorskip("torch")

from cli_contract import refused, succeeded  # noqa: E402
from pipe_guard import within  # noqa: E402

from pipeline.data.cache import ClipSet  # noqa: E402
from pipeline.data.pack import pack  # noqa: E402

RUN = ["--steps", "4", "--path-steps", "0", "--batch", "2", "--lengths", "64", "--adv-start", "-1"]


def _clips(lengths=(150, 140), seed: int = 0) -> ClipSet:
    """Clips of random unit quaternions on the model skeleton (21 joints): no split's."""
    rng = np.random.default_rng(seed)
    lengths = np.array(lengths, np.int64)
    n = int(lengths.sum())
    q = rng.normal(size=(n, 21, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    roots = np.cumsum(rng.normal(size=(n, 3)), axis=0) + [0, 90, 0]
    names = [f"packed_{seed}_{i}" for i in range(len(lengths))]
    return ClipSet(
        names, np.cumsum(lengths) - lengths, lengths, q.astype(np.float32), roots.astype(np.float32), 30.0
    )


@pytest.fixture
def decodes(monkeypatch):
    """The pack decodes of the test (a list of paths), none kept from an earlier test."""
    import pipeline.data.pack as packmod
    from pipeline.train import generator_training

    monkeypatch.setattr(generator_training, "_PACKED", [], raising=False)
    calls, load = [], packmod.load_pack

    def counted(path, option=None):
        calls.append(str(path))
        return load(path, option)

    monkeypatch.setattr(packmod, "load_pack", counted)
    return calls


def test_the_path_predictor_trains_on_the_pack_without_the_shared_data(tmp_path, monkeypatch, decodes):
    import pipeline.train.path_training as pt

    path = pack(_clips(), tmp_path / "train.pack")
    monkeypatch.setenv("TWEEN_DATA", str(tmp_path / "no_shared_data"))  # a GPU host: no ../shared
    seen = []
    sample = pt.sample_batch
    monkeypatch.setattr(
        pt, "sample_batch", lambda clips, *a, **k: seen.append(clips.names) or sample(clips, *a, **k)
    )
    ckpt = pt.train_path(pt.PathTrainConfig(steps=4, batch=2, data_pack=str(path)), tmp_path / "run")
    assert ckpt.is_file() and seen == [["packed_0_0", "packed_0_1"]] * 4
    # The generator's stage then takes the same decoded clips; a pack written again is decoded again.
    from pipeline.train.generator_training import packed_clips

    assert packed_clips(str(path)).names == ["packed_0_0", "packed_0_1"] and decodes == [str(path)]
    pack(_clips(seed=1), path)
    assert packed_clips(str(path)).names == ["packed_1_0", "packed_1_1"] and len(decodes) == 2


def test_a_run_decodes_its_pack_once(tmp_path, capsys, monkeypatch, decodes):
    path = pack(_clips(), tmp_path / "train.pack")
    monkeypatch.setenv("TWEEN_DATA", str(tmp_path / "no_shared_data"))
    succeeded(["train", "--out", tmp_path / "run", *RUN, "--data-pack", path], capsys)
    assert decodes == [str(path)]  # the up-front check's decode is the training's


def test_data_beside_a_pack_is_refused_naming_both(tmp_path, capsys, bandai_clip):
    """The pack was trained on and the takes passed over, unsaid."""
    path = pack(_clips(), tmp_path / "train.pack")
    takes = tmp_path / "takes"
    takes.mkdir()
    (takes / bandai_clip.name).write_bytes(bandai_clip.read_bytes())
    line = refused(
        ["train", "--out", tmp_path / "run2", *RUN, "--data-pack", path, "--data", takes], capsys, tmp_path
    )
    assert line.endswith(f": --data-pack {path}: holds the clips to train on; drop --data {takes}"), line


def test_a_pipe_as_init_is_said_to_be_one(tmp_path, capsys):
    fifo = tmp_path / "init.pt"
    os.mkfifo(fifo)
    line = within(
        lambda: refused(["train", "--out", tmp_path / "run", *RUN, "--init", fifo], capsys, tmp_path), [fifo]
    )
    assert line == (
        f"tween: error: {fifo}: --init: not a regular file (a pipe, socket or device), not a checkpoint"
    ), line
    line = refused(
        ["train", "--out", tmp_path / "run", *RUN, "--init", tmp_path / "none.pt"], capsys, tmp_path
    )
    assert line == f"tween: error: {tmp_path / 'none.pt'}: --init checkpoint not found"


def test_tween_train_hands_the_pack_to_the_path_predictor(tmp_path, capsys, monkeypatch, decodes):
    """The command line built the path predictor's config without --data-pack, so its stage
    read the train split from ../shared (and failed on a host without it)."""
    import pipeline.train.path_training as pt

    path = pack(_clips(), tmp_path / "train.pack")
    monkeypatch.setenv("TWEEN_DATA", str(tmp_path / "no_shared_data"))
    seen = []
    sample = pt.sample_batch
    monkeypatch.setattr(
        pt, "sample_batch", lambda clips, *a, **k: seen.append(clips.names) or sample(clips, *a, **k)
    )
    args = [a if a != "0" else "3" for a in RUN]  # --path-steps 3
    succeeded(["train", "--out", tmp_path / "run", *args, "--data-pack", path], capsys)
    assert seen == [["packed_0_0", "packed_0_1"]] * 3 and decodes == [str(path)]
