"""The one error handler (pipeline.command) and the truth of every error hint in the code."""

from __future__ import annotations

import ast
import errno
from pathlib import Path

import pytest
import typer
from cli_contract import OPTION, OTHER, commands, options_of

from pipeline import command
from pipeline.errors import ShotError

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("pipeline", "workers", "render", "dailies")


def _app(fail):
    app = typer.Typer(add_completion=False, pretty_exceptions_enable=False)

    @app.command()
    def go(path: str = "x"):
        fail(path)

    @app.command()
    def other():
        pass

    return app


def _run(app, argv, tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        command.run(app, argv, log_dir=tmp_path / "logs")
    return e.value.code, capsys.readouterr().err


def test_an_error_the_user_can_act_on_is_one_line_exit_2(tmp_path, capsys):
    def fail(path):
        raise ShotError(path, "no SkelAnimation", "/World/Skel")

    code, err = _run(_app(fail), ["go", "--path", "shot.usda"], tmp_path, capsys)
    assert code == 2 and err == "tween: error: shot.usda /World/Skel: no SkelAnimation\n"


def test_an_error_naming_a_file_with_a_newline_or_escape_code_stays_one_line(tmp_path, capsys):
    def fail(path):
        raise ShotError("takes/bad\nname\x1b[31m.bvh", "expected HIERARCHY")

    code, err = _run(_app(fail), ["go"], tmp_path, capsys)
    assert code == 2 and err == "tween: error: takes/bad\\nname\\x1b[31m.bvh: expected HIERARCHY\n"


@pytest.mark.parametrize(
    "exc, line",
    [
        (PermissionError(errno.EACCES, "Permission denied", "/studio/out"), "/studio/out: Permission denied"),
        (
            OSError(errno.EROFS, "Read-only file system", "/mnt/ro/x.usda"),
            "/mnt/ro/x.usda: Read-only file system",
        ),
        (OSError(errno.ENOSPC, "No space left on device"), "No space left on device: the disk"),
        (OSError(errno.EFBIG, "File too large"), "File too large: the disk (or the file-size limit) is full"),
    ],
)
def test_operating_system_errors_are_one_line_naming_the_file(tmp_path, capsys, exc, line):
    def fail(path):
        raise exc

    code, err = _run(_app(fail), ["go"], tmp_path, capsys)
    assert code == 2 and err.startswith(f"tween: error: {line}") and err.count("\n") == 1


def test_a_bug_says_so_and_where_its_traceback_is(tmp_path, capsys):
    def fail(path):
        return {}["missing key"]

    code, err = _run(_app(fail), ["go"], tmp_path, capsys)
    assert code == 1 and err.count("\n") == 1
    assert err.startswith("tween: internal error (a bug in usd-tween, not in your input): KeyError")
    log = Path(err.rsplit("the traceback is in ", 1)[1].strip())
    assert log.parent == tmp_path / "logs" and 'return {}["missing key"]' in log.read_text()


def test_an_os_error_naming_no_file_and_no_disk_is_a_bug_too(tmp_path, capsys):
    def fail(path):
        raise ConnectionResetError(errno.ECONNRESET, "Connection reset by peer")

    code, err = _run(_app(fail), ["go"], tmp_path, capsys)
    assert code == 1 and "internal error" in err


def test_usage_errors_and_interrupts_keep_their_lines(tmp_path, capsys):
    def fail(path):
        raise KeyboardInterrupt

    code, err = _run(_app(fail), ["go", "--nope"], tmp_path, capsys)
    assert code == 2 and err.startswith("tween: error: go: No such option: --nope") and err.count("\n") == 1
    code, err = _run(_app(fail), ["go"], tmp_path, capsys)
    assert code == 130 and err == "tween: interrupted\n"


# A command whose import swallows what is raised inside it, as USD's module loader
# (Tf.PreparePythonModule) does, then takes a while and writes its result.
SWALLOWING_IMPORT = """
import os, signal, sys, time
sys.path.insert(0, sys.argv[1])
import typer
from pipeline import command

app = typer.Typer(add_completion=False)

@app.command()
def go():
    import swallower  # its import is signalled, and it swallows what is raised there
    time.sleep(1.0)
    open(os.path.join(sys.argv[1], "written"), "w").close()

command.run(app, [])
"""
SWALLOWER = """
import os, signal, time
try:
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(0.2)
except BaseException:
    pass
"""


def test_an_interrupt_that_lands_inside_an_import_is_not_lost(tmp_path):
    """SIGTERM 2.2 s into `tween fill` landed in USD's module loader, which caught and printed
    the interrupt: the fill ran on, wrote its layer and exited 0. Inside an import the signal
    is sent again a moment later, and lands in the command: 130, nothing written."""
    import subprocess
    import sys

    (tmp_path / "swallower.py").write_text(SWALLOWER)
    script = tmp_path / "cmd.py"
    script.write_text(SWALLOWING_IMPORT)
    res = subprocess.run([sys.executable, str(script), str(tmp_path)], capture_output=True, text=True,
                         timeout=60, cwd=ROOT)  # fmt: skip
    assert res.returncode == 130 and res.stderr == "tween: interrupted\n", res.stderr
    assert not (tmp_path / "written").exists()


def test_an_interrupt_while_the_command_line_loads_is_one_line(tmp_path):
    """Ctrl-C in the first half second of any command (the CLI's imports, before the handler
    of pipeline.command is set) printed a 20-35 line traceback. The Ctrl-C lands as the CLI
    starts to import (a finder sends it), not after a sleep: on a warm, idle machine the CLI
    loaded and --help exited before a 0.25 s sleep was over."""
    import subprocess
    import sys

    entry = (
        "import os, signal, sys\n"
        "sys.argv[0] = 'tween'\n"
        "class CtrlC:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'pipeline.cli':\n"
        "            os.kill(os.getpid(), signal.SIGINT)\n"
        "        return None\n"
        "sys.meta_path.insert(0, CtrlC())\n"
        "from pipeline.entry import main\n"
        "main()\n"
    )
    proc = subprocess.run([sys.executable, "-c", entry, "--help"], cwd=ROOT, capture_output=True, text=True,
                          timeout=60)  # fmt: skip
    assert proc.returncode == 130 and proc.stderr == "tween: interrupted\n" and proc.stdout == "", proc.stderr


def test_a_signal_as_the_finished_command_shuts_down_leaves_its_status(tmp_path):
    """SIGTERM or Ctrl-C as Python tore its modules down, after the command had written
    everything and said so (a publish, a library build, a review), killed the process by the
    signal: status -15 or -2, no line, the finished output looking interrupted. The signal
    comes from an object of the script torn down with it, after Python resets its handlers."""
    import subprocess
    import sys

    entry = (
        "import os, signal, sys, time\n"
        "sys.argv[0] = 'tween'\n"
        "class Late:\n"
        "    def __del__(self):\n"
        "        os.kill(os.getpid(), signal.{})\n"
        "        time.sleep(0.3)\n"
        "late = Late()\n"
        "from pipeline.entry import main\n"
        "main()\n"
    )
    for sig in ("SIGTERM", "SIGINT"):
        proc = subprocess.run([sys.executable, "-c", entry.format(sig), "--help"], cwd=ROOT, capture_output=True,
                              text=True, timeout=60)  # fmt: skip
        assert proc.returncode == 0 and "Usage" in proc.stdout and proc.stderr == "", (sig, proc.returncode)


# ------------------------------------------------------------------------------- hints


def _modules() -> dict[str, Path]:
    out = {}
    for top in PACKAGES:
        for p in sorted((ROOT / top).rglob("*.py")) if (ROOT / top).is_dir() else []:
            out[".".join(p.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")] = p
    return out


def _imports(path: Path, modules: dict) -> set[str]:
    """The project modules ``path`` imports anywhere (module level or inside functions)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        for n in names:
            parts = n.split(".")
            found |= {".".join(parts[:i]) for i in range(1, len(parts) + 1)} & set(modules)
    return found


def _reach(start: str, graph: dict) -> set[str]:
    seen, todo = {start}, [start]
    while todo:
        for b in graph.get(todo.pop(), ()):
            if b not in seen:
                seen.add(b)
                todo.append(b)
    return seen


def _hint_texts(path: Path):
    """(line, text) of every message the module raises or builds for an error: the strings of
    each ``raise`` and of functions named ``*message``, ``*hint`` or ``*_line``."""
    tree = ast.parse(path.read_text())
    roots = [n for n in ast.walk(tree) if isinstance(n, ast.Raise) and n.exc is not None]
    roots += [n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)
              and n.name.endswith(("message", "hint", "_line"))]  # fmt: skip
    for r in roots:
        inner = {id(c) for n in ast.walk(r) if isinstance(n, ast.JoinedStr) for c in n.values}
        for n in ast.walk(r):
            if isinstance(n, ast.JoinedStr):  # an f-string: its text with {} where values go
                text = "".join(v.value if isinstance(v, ast.Constant) else "{}" for v in n.values)
            elif isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in inner:
                text = n.value
            else:
                continue
            if "--" in text:
                yield n.lineno, text


def test_every_error_hint_names_options_that_its_commands_take():
    """An error's hint names options; each must be taken by a command that can print it (one
    whose code reaches the module), or by the command a ``tween OTHER …`` phrase names."""
    modules = _modules()
    graph = {m: _imports(p, modules) for m, p in modules.items()}
    reach = {name: _reach(cmd.callback.__module__, graph) for name, cmd in commands().items() if cmd.callback}
    checked, bad = 0, []
    for mod, path in modules.items():
        printers = [c for c, r in reach.items() if mod in r]
        for line, text in _hint_texts(path):
            where = f"{path.relative_to(ROOT)}:{line}"
            spans = []
            for m in OTHER.finditer(text):
                other = m.group(1)
                if other not in commands():
                    continue
                spans.append(m.span())
                bad += [
                    f"{where}: tween {other} {o}"
                    for o in OPTION.findall(m.group(0))
                    if o not in options_of(other)
                ]
            rest = "".join(" " if any(a <= i < b for a, b in spans) else ch for i, ch in enumerate(text))
            for opt in OPTION.findall(rest):
                checked += 1
                if printers and not any(opt in options_of(c) for c in printers):
                    bad.append(f"{where}: {opt} (printed by {', '.join(sorted(printers))})")
    assert checked > 20  # the scan finds the hints (a broken pattern would pass vacuously)
    assert not bad, "error hints naming options their commands do not take:\n" + "\n".join(bad)
