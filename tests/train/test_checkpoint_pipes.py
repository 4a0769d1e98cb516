"""A pipe where a run's checkpoint or log is read (a run folder's generator.pt on resume or
export, train_log.jsonl on resume, a --init, train-rig's state.pt) blocked torch.load or the
log's read for ever; each is one line naming it, at once."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from pipe_guard import within

from pipeline.errors import TweenError


def test_a_pipe_as_a_checkpoint_is_refused_naming_it(tmp_path):
    from pipeline.train.generator_training import read_checkpoint

    fifo = tmp_path / "generator.pt"
    os.mkfifo(fifo)
    with pytest.raises(TweenError, match=r"generator\.pt: --init: not a regular file \(a pipe"):
        within(lambda: read_checkpoint(fifo, "--init"), [fifo])


def test_a_pipe_as_the_run_log_is_refused_naming_it(tmp_path):
    from pipeline.train.generator_training import resumed_log

    fifo = tmp_path / "train_log.jsonl"
    os.mkfifo(fifo)
    with pytest.raises(TweenError, match=r"train_log\.jsonl: not a regular file \(a pipe"):
        within(lambda: resumed_log(fifo, 25), [fifo])


def test_a_pipe_as_a_rig_training_state_is_refused_naming_it(tmp_path):
    from pipeline.rig.train import Trainer, TrainError

    fifo = tmp_path / "state.pt"
    os.mkfifo(fifo)
    trainer = Trainer.__new__(Trainer)  # only _read_state is asked: no schedule, no clip
    trainer.device = "cpu"
    with pytest.raises(TrainError, match=r"state\.pt: cannot read the checkpoint: not a regular file"):
        within(lambda: trainer._read_state(Path(fifo)), [fifo])
