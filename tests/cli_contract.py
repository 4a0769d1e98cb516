"""The contract every `tween` command keeps with bad input, as one assertion for the tests.

A refused command prints exactly one ``tween: error:`` line on stderr and nothing before it,
exits with status 2, leaves every watched folder exactly as it was (no file made, changed or
removed), and every option its line names is one the command accepts.
"""

from __future__ import annotations

import re
from functools import cache
from pathlib import Path

import pytest

#: ``--flag`` as an option name in a message (not ``---`` rules, not inside a word).
OPTION = re.compile(r"(?<![\w-])--[a-z][a-z0-9]*(?:-[a-z0-9]+)*")
#: ``tween <command> … --flag``: a hint that names another command's option.
OTHER = re.compile(r"`?tween ([a-z][a-z-]*)((?:\s+(?!tween\b)[^\s`;,()]+)*)")


def snapshot(*folders: Path) -> dict:
    """Every path under ``folders`` (and whether each folder exists) with its size and mtime."""
    out = {}
    for f in folders:
        f = Path(f)
        out[str(f)] = f.exists()
        if f.is_dir():
            for p in sorted(f.rglob("*")):
                st = p.lstat()
                out[str(p)] = (st.st_size, st.st_mtime_ns, p.is_dir())
    return out


@cache
def commands() -> dict:
    """``tween``'s click commands by name (``train`` with its real options)."""
    import typer

    from pipeline.cli import app

    group = typer.main.get_command(app)
    found = dict(group.commands)
    try:
        from pipeline.train.recipe import train_command

        found["train"] = train_command()
    except ImportError:  # no torch: `tween train` cannot run here either
        pass
    for name, cmd in list(found.items()):
        for sub_name, sub in getattr(cmd, "commands", {}).items():  # `tween library build`
            found[f"{name} {sub_name}"] = sub
    return found


def options_of(command: str) -> set[str]:
    cmd = commands()[command]
    return {o for p in cmd.params for o in (*p.opts, *p.secondary_opts) if o.startswith("--")} | {"--help"}


def command_of(argv: list[str]) -> str:
    """The command name an argument list runs (``library build`` for a group's command)."""
    if len(argv) > 1 and f"{argv[0]} {argv[1]}" in commands():
        return f"{argv[0]} {argv[1]}"
    return argv[0]


def untrue_hints(command: str, line: str) -> list[str]:
    """The options ``line`` names that its command does not take (or, in a ``tween OTHER …``
    phrase, that OTHER does not take)."""
    bad, spans = [], []
    for m in OTHER.finditer(line):
        other = " ".join(m.group(1).split()[:1])
        words = m.group(2).split()
        if words and f"{other} {words[0]}" in commands():
            other = f"{other} {words[0]}"
        if other not in commands():
            bad.append(f"tween {other}")
            continue
        spans.append(m.span())
        bad += [o for o in OPTION.findall(m.group(0)) if o not in options_of(other)]
    rest = "".join(ch if not any(a <= i < b for a, b in spans) else " " for i, ch in enumerate(line))
    bad += [o for o in OPTION.findall(rest) if o not in options_of(command)]
    return bad


def refused(argv: list[str], capsys, *watch: Path, code: int = 2) -> str:
    """Runs ``tween ARGV`` in this process; asserts the contract; returns the error line."""
    from pipeline.cli import main

    before = snapshot(*watch)
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main([str(a) for a in argv])
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert e.value.code == code, f"tween {argv}: exit {e.value.code}, stderr:\n{err[-3000:]}"
    assert len(lines) == 1 and lines[0].startswith("tween: error: "), f"tween {argv}: stderr:\n{err[-3000:]}"
    assert snapshot(*watch) == before, f"tween {argv} changed {watch}"
    # An option-like value the user gave, echoed back in the error, is no hint of ours.
    bad = [
        o
        for o in untrue_hints(command_of([str(a) for a in argv]), lines[0])
        if not any(o in str(a) for a in argv)
    ]
    assert not bad, f"tween {argv}: its error names options it does not take: {bad}\n{lines[0]}"
    return lines[0]


def failed(argv: list[str], capsys, code: int = 2) -> str:
    """Runs ``tween ARGV`` that fails while working (a full disk): progress may come first,
    then exactly one ``tween: error:`` line and no traceback. Returns that line."""
    from pipeline.cli import main

    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert e.value.code == code, f"tween {argv}: exit {e.value.code}, stderr:\n{err[-3000:]}"
    last = err.rstrip("\n").rsplit("\n", 1)[-1]
    assert last.startswith("tween: error: ") and err.count("tween: error:") == 1, err[-3000:]
    assert "Traceback" not in err, err[-3000:]
    return last


def succeeded(argv: list[str], capsys) -> str:
    """Runs ``tween ARGV`` in this process; asserts exit 0; returns its stdout."""
    from pipeline.cli import main

    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert e.value.code == 0, err[-3000:]
    return out
