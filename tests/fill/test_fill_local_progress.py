"""`tween fill-local` shows its progress on a terminal's stderr (a bar over the takes × the
characters, then the layers), as `tween library build` does: 41 s of silence for a 16-character
shot of 30,000 frames. stdout stays the JSON result; in a log or a pipe stderr stays its lines;
a refused shot is still its one line, with no bar begun before it."""

from __future__ import annotations

import fcntl
import json
import os
import re
import struct
import sys
import termios
import threading
import time
from pathlib import Path

import pytest
from usd_fixtures import bandai_shot

from pipeline.errors import TweenError
from pipeline.fill import api
from pipeline.fill import cli as fill_cli
from pipeline.fill.api import FillOptions, fill_shot

BAR = re.compile(r"fill two\.usda: +(\d+)%\|[^|\r\n]*\| (\d+)/(\d+) ")


@pytest.fixture(scope="module")
def two(tmp_path_factory) -> Path:
    """A shot of two characters (the example's walker and a copy of it)."""
    from pxr import Sdf

    shot = bandai_shot(tmp_path_factory.mktemp("two") / "two.usda", frames=61, keys_every=10)
    layer = Sdf.Layer.FindOrOpen(str(shot))
    assert Sdf.CopySpec(layer, "/World/Character", layer, "/World/Second")
    layer.Save()
    return shot


class Terminal:
    """A real terminal (a pty) as this process's stderr; what was drawn on it, once closed."""

    def __init__(self, monkeypatch):
        self.primary, replica = os.openpty()
        # A new pty is 0 columns wide, where tqdm draws nothing; a terminal window is wider.
        fcntl.ioctl(replica, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 120, 0, 0))
        self.chunks: list[bytes] = []
        self.reader = threading.Thread(target=self._drain, daemon=True)  # a full pty would block
        self.reader.start()
        self.tty = os.fdopen(replica, "w", buffering=1)
        assert self.tty.isatty()
        monkeypatch.setattr(sys, "stderr", self.tty)

    def _drain(self) -> None:
        while True:
            try:
                data = os.read(self.primary, 4096)
            except OSError:  # EIO: the replica side is closed
                return
            if not data:
                return
            self.chunks.append(data)

    def text(self) -> str:
        self.tty.close()
        self.reader.join(10)
        os.close(self.primary)
        return b"".join(self.chunks).decode()


def screen(drawn: str) -> list[str]:
    """The lines a terminal shows after ``drawn``: a carriage return writes over its line
    from the first column (a bar's redraws, its wiping)."""
    shown = []
    for line in drawn.replace("\r\n", "\n").split("\n"):
        row = ""
        for part in line.split("\r"):
            row = part + row[len(part) :]
        shown.append(row.rstrip())
    return [row for row in shown if row]


def _tween(*args) -> int:
    from pipeline.cli import main

    with pytest.raises(SystemExit) as e:
        main(["fill-local", *map(str, args)])
    return e.value.code or 0


def test_a_terminal_shows_the_fill_bar_and_stdout_stays_the_json(two, tmp_path, monkeypatch, capsys):
    from pipeline.fill import solve

    monkeypatch.setattr(fill_cli, "BAR_DELAY", 0)  # a test's fill is quicker than the bar's delay
    real = solve.fill_character

    def noted(plan, cp, *a, seed, **k):  # a note said mid-fill, as a trust decision is
        if seed == 0:
            print(f"tween: note on {cp.char.anim_path}", file=sys.stderr)
        return real(plan, cp, *a, seed=seed, **k)

    monkeypatch.setattr(solve, "fill_character", noted)
    term = Terminal(monkeypatch)
    rc = _tween(two, "--model", "interp", "--takes", "3", "--out-dir", tmp_path / "out")
    drawn = term.text()
    out = capsys.readouterr().out
    assert rc == 0, drawn
    result = json.loads(out)  # stdout is the result alone: no bar in it
    assert result["takes"] == 3 and len(result["characters"]) == 2, out
    # 3 takes × 2 characters, then the layers: 7 steps, the last drawn when the fill is written.
    bars = [m.groups() for m in BAR.finditer(drawn)]
    assert bars and all(t == "7" for _, _, t in bars), drawn
    assert bars[-1][:2] == ("100", "7"), drawn
    # The plan's notes come before the bar, the notes said mid-fill above it, and the last line
    # after it, each a line of its own; the bar is left done.
    lines = screen(drawn)
    assert len(lines) == 6, lines
    assert lines[2:4] == [
        f"tween: note on {a}" for a in ("/World/Character/Skel/Anim", "/World/Second/Skel/Anim")
    ]
    assert lines[4].startswith("fill two.usda: 100%|") and "| 7/7 [" in lines[4], lines
    assert lines[5] == f"tween: filled {two} -> {result['layer']}", lines
    assert all(" human model interpolation" in ln and ln.startswith(f"tween: {two} ") for ln in lines[:2]), (
        lines
    )


def test_no_bar_in_a_log_or_with_no_progress(two, tmp_path, monkeypatch, capsys):
    """Not a terminal (a pipe, a log file, the tests' capture), or --no-progress: stderr is
    the notes and the last line as before, which scripts and tests count."""
    monkeypatch.setattr(fill_cli, "BAR_DELAY", 0)
    rc = _tween(two, "--model", "interp", "--takes", "2", "--out-dir", tmp_path / "a")
    got = capsys.readouterr()
    assert rc == 0 and json.loads(got.out)["takes"] == 2
    lines = got.err.splitlines()
    assert "\r" not in got.err and "%|" not in got.err and len(lines) == 3, got.err
    assert lines[-1].startswith(f"tween: filled {two} -> "), got.err
    term = Terminal(monkeypatch)
    rc = _tween(two, "--model", "interp", "--no-progress", "--out-dir", tmp_path / "b")
    drawn = term.text()
    assert rc == 0 and "%|" not in drawn and "\r\n" in drawn, drawn
    assert json.loads(capsys.readouterr().out)["takes"] == 1


def test_a_refused_shot_on_a_terminal_is_one_line_and_no_bar(two, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(fill_cli, "BAR_DELAY", 0)
    term = Terminal(monkeypatch)
    rc = _tween(two, "--model", "interp", "--keys", "5001-5061x10", "--out-dir", tmp_path / "out")
    drawn = term.text()
    lines = screen(drawn)
    assert rc == 2 and len(lines) == 1 and lines[0].startswith(f"tween: error: {two}"), drawn
    assert "%|" not in drawn and capsys.readouterr().out == "" and not (tmp_path / "out").exists()


def test_a_fill_that_fails_midway_wipes_its_bar_before_the_error_line(two, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(fill_cli, "BAR_DELAY", 0)

    def full(*a, **k):
        raise TweenError(f"{tmp_path}: the disk is full")

    monkeypatch.setattr(api, "write_layers", full)
    term = Terminal(monkeypatch)
    rc = _tween(two, "--model", "interp", "--takes", "2", "--out-dir", tmp_path)
    drawn = term.text()
    assert rc == 2 and capsys.readouterr().out == "", drawn
    assert BAR.search(drawn), drawn  # the bar was shown while the takes were filled
    # ... and wiped: the terminal shows the plan's two notes and the error line, no bar.
    lines = screen(drawn)
    assert len(lines) == 3 and lines[2] == f"tween: error: {tmp_path}: the disk is full", lines


def test_fill_shot_reports_each_character_of_each_take_then_the_layers(two, tmp_path):
    calls = []
    res = fill_shot(str(two), FillOptions(model="interp", takes=2, out_dir=str(tmp_path)),
                    on_progress=lambda *a: calls.append(a))  # fmt: skip
    assert res["takes"] == 2
    done = [d for d, _, _ in calls]
    assert {t for _, t, _ in calls} == {5} and done[0] == 0 and done[-1] == 5, calls
    assert done == sorted(done) and set(done) == {0, 1, 2, 3, 4, 5}, calls
    nexts = dict((d, w) for d, _, w in calls)
    assert (
        nexts[0] == "take 1/2 /World/Character/Skel/Anim" and nexts[1] == "take 1/2 /World/Second/Skel/Anim"
    )
    assert nexts[4] == "writing the layers" and nexts[5] == "", calls
    # A refused shot says nothing to it: it is called once the shot has been validated.
    calls.clear()
    with pytest.raises(TweenError):
        fill_shot(
            str(two), FillOptions(model="interp", keys="5001-5061x10"), on_progress=lambda *a: calls.append(a)
        )
    assert calls == []


def test_the_clock_runs_through_a_long_step(two, tmp_path, monkeypatch, capsys):
    """Writing the layers of 16 characters × 30,000 frames took 24 s, one step: the bar is
    redrawn meanwhile (its elapsed time runs), not frozen at its last step."""
    monkeypatch.setattr(fill_cli, "BAR_DELAY", 0)
    monkeypatch.setattr(fill_cli, "TICK", 0.1)
    real = api.write_layers

    def slow(*a, **k):
        time.sleep(1.0)
        return real(*a, **k)

    monkeypatch.setattr(api, "write_layers", slow)
    term = Terminal(monkeypatch)
    rc = _tween(two, "--model", "interp", "--out-dir", tmp_path)
    drawn = term.text()
    assert rc == 0 and json.loads(capsys.readouterr().out)["takes"] == 1, drawn
    during = [seg for seg in drawn.split("\r") if "| 2/3 [" in seg and "writing the layers" in seg]
    assert len(during) >= 2, drawn  # 10 ticks in the 1 s step; 2 on a loaded machine
    assert screen(drawn)[-2].startswith("fill two.usda: 100%|"), drawn
