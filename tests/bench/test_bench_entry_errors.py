"""The benches' (and the data tools') ``python -m`` entry points answer bad input as every ``tween`` command does:
one ``tween: error:`` line on stderr, exit status 2, nothing written (pipeline.command.run_main,
pipeline.arguments.Parser)."""

from __future__ import annotations

import contextlib
import io
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.command import run_main
from pipeline.errors import TweenError, printable


@pytest.mark.parametrize(
    "module, args, says",
    [
        ("pipeline.bench.blocking", ["--sources", "eval", "--limit", "1", "--every", "10"], "raise --limit"),
        ("pipeline.bench.blocking", ["--sources", "bogus"], "--sources: unknown source 'bogus'"),
        ("pipeline.bench.trust_bench", ["--sources", "bogus"], "--sources: unknown source 'bogus'"),
        ("pipeline.bench.trust_bench", ["--sources", "posture30", "--limit", "3"], "raise --limit"),
        ("pipeline.bench.studio", ["--subjects", "99"], "no CMU takes of subjects 99 there"),
        # Values no bench can run on, refused by their argument types (pipeline.bench.args).
        ("pipeline.bench.studio", ["--every", "0"], "argument --every: 0: a key spacing"),
        ("pipeline.bench.studio", ["--subjects", "a"], "argument --subjects: 'a': a subject number"),
        ("pipeline.bench.studio", ["--fps", "nan"], "argument --fps: 'nan': a frame rate"),
        ("pipeline.bench.library", ["--stride", "0"], "argument --stride: 0: a stride"),
        ("pipeline.bench.library", ["--every", "10,x"], "argument --every: 'x': a key spacing"),
        ("pipeline.bench.blocking", ["--limit", "0"], "argument --limit: 0: a count"),
        ("pipeline.bench.trust_bench", ["--bogus"], "unrecognized arguments: --bogus"),
        ("render.bench", ["--pngg"], "python -m render.bench: unrecognized arguments: --pngg"),
        ("pipeline.data.posebank", ["--poses", "0"], "argument --poses: 0: must be at least 1"),
        ("pipeline.data.posebank", ["--poses", "5", "NOFOLDER"], "is not a folder that exists"),
        ("pipeline.data.posebank", ["--seed", "x"], "argument --seed: invalid int value: 'x'"),
        ("pipeline.data.pack", ["--bogus"], "python -m pipeline.data.pack: unrecognized arguments: --bogus"),
        (
            "pipeline.train.corpus",
            [],
            "python -m pipeline.train.corpus: the following arguments are required",
        ),
    ],
)
def test_a_bench_entry_point_refuses_bad_input_in_one_line(tmp_path, module, args, says):
    out = tmp_path / "out"
    if module in ("pipeline.data.pack", "pipeline.train.corpus"):
        args = [*args, str(out / "x")] if args else args  # what --out would name
    elif module == "pipeline.data.posebank":  # its output is a file argument, not --out
        args = [a.replace("NOFOLDER", str(out / "bank.npz")) for a in args] + (
            [str(out)] if "NOFOLDER" not in args else []
        )
    else:
        args = [*args, "--out", str(out)]
    r = subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True, timeout=300)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2, r.stderr[-2000:]
    if "argument" in says:  # pipeline.arguments.Parser: one line, before anything runs
        assert len(lines) == 1, r.stderr[-2000:]
    # A later refusal may come after a cold cache's progress lines; the error is one line.
    errors = [ln for ln in lines if "error" in ln]
    assert len(errors) == 1 and errors[0].startswith("tween: error: ") and says in errors[0], r.stderr[-2000:]
    assert "Traceback" not in r.stderr and "usage:" not in r.stderr
    assert not out.exists()


@settings(max_examples=30, deadline=None)
@given(kind=st.sampled_from(["user", "file", "bug", "ok"]), text=st.text(min_size=1, max_size=40))
def test_run_main_by_generation(kind, text):
    """Whatever the entry point raises, run_main exits 2 for the user's errors (one line
    naming the file for an OS error on one), 1 for anything else, else the entry's status."""

    def main(argv):
        if kind == "user":
            raise TweenError(text)
        if kind == "file":
            raise FileNotFoundError(2, "No such file or directory", f"/nowhere/{len(text)}.usda")
        if kind == "bug":
            raise KeyError(text)
        return 0

    err = io.StringIO()
    logs = Path(tempfile.mkdtemp())
    with pytest.raises(SystemExit) as done, contextlib.redirect_stderr(err):
        run_main(main, [], log_dir=logs)
    assert done.value.code == {"user": 2, "file": 2, "bug": 1, "ok": 0}[kind]
    first = (err.getvalue().splitlines() or [""])[0]
    if kind == "user":  # one line, whatever the text holds (control characters escaped)
        assert err.getvalue() == printable(f"tween: error: {text}") + "\n"
    elif kind == "file":
        assert first == f"tween: error: /nowhere/{len(text)}.usda: No such file or directory"
    elif kind == "bug":
        assert first.startswith("tween: internal error (a bug in usd-tween, not in your input): KeyError")
        assert len(err.getvalue().splitlines()) == 1 and len(list(logs.iterdir())) == 1  # the traceback
    else:
        assert err.getvalue() == ""


def test_trust_bench_sources_keep_cmu_subjects_and_are_checked_first():
    from pipeline.bench.trust_bench import parse_sources

    assert parse_sources("eval,cmu:5,6,7,posture30") == ("eval", "cmu:5,6,7", "posture30")
    assert parse_sources("cmu,posture10,mirrored") == ("cmu", "posture10", "mirrored")
    for bad in ("eval,bogus", "cmu:x", "posturex", "eval,5"):
        with pytest.raises(TweenError):
            parse_sources(bad)
