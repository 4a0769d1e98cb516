"""A pipe (FIFO) named like the shot's next review layer, with no fill layer of that version:
approve, publish and review opened it with USD to name the fill it stacks, and waited for a
writer for ever (pipeline.usd.write._stacked_fill). It is read as a review layer USD cannot
read: the latest fill is missing, one line, nothing written."""

from __future__ import annotations

import os
import subprocess
import sys

from pipe_guard import within
from usd_fixtures import bandai_shot, tree_hashes

from pipeline.fill.api import FillOptions, fill_shot


def _tween(*args) -> tuple[int, str]:
    r = subprocess.run(
        [sys.executable, "-m", "pipeline.cli", *map(str, args)], capture_output=True, text=True
    )
    return r.returncode, r.stderr


def test_a_pipe_as_the_next_review_layer_holds_no_command(tmp_path):
    shot = bandai_shot(tmp_path / "sh030.usda", frames=21, keys_every=10)
    assert fill_shot(str(shot), FillOptions(model="interp"))["version"] == 1
    fifo = tmp_path / "sh030.review.v002.usda"
    os.mkfifo(fifo)
    before = tree_hashes(tmp_path)
    for args in (("approve", shot, "--take", "0"), ("publish", shot)):
        code, err = within(lambda a=args: _tween(*a), [fifo])
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1, (args, err)
        assert lines[0].startswith(
            f"tween: error: {tmp_path / 'sh030.tween.v002.usda'}: the latest fill of"
        ), err
    assert tree_hashes(tmp_path) == before
