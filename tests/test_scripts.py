"""The scripts (``scripts/``: tools for what ships) and the experiments (``experiments/``: one-off
studies, outside the installed packages) use public APIs only (issue 18): each imports without
running, takes ``--help``, and imports nothing but the standard library, installed libraries and
the project's packages (no ``sys.path`` edits, no script importing another). Code they shared
lives in the package (pipeline.bench.selection, pipeline.bench.ratios), tested here."""

from __future__ import annotations

import ast
import importlib
import importlib.util
import inspect
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
FOLDERS = ("scripts", "experiments")
SCRIPTS = sorted(p for folder in FOLDERS for p in (REPO / folder).glob("*.py"))
#: Needs Blender's ``bpy`` for two of its commands (imported lazily): checked with --help only.
BPY = "blender_roundtrip.py"
PLAIN = [p for p in SCRIPTS if p.name != BPY]
PROJECT = ("pipeline", "workers", "render", "usd_schemas")


def _id(p: Path) -> str:
    return f"{p.parent.name}/{p.stem}"


def test_there_are_scripts():
    assert len(SCRIPTS) >= 2 and any(p.name == BPY for p in SCRIPTS)


def test_every_experiment_says_what_it_measured():
    """experiments/README.md has a row for each experiment (what it measured, where the
    result is), and the package does not ship the folder."""
    readme = (REPO / "experiments" / "README.md").read_text()
    for p in (REPO / "experiments").glob("*.py"):
        assert f"| `{p.name}` |" in readme, f"experiments/README.md: no row for {p.name}"
    setup = (REPO / "setup.py").read_text()
    assert "find_packages(include=" in setup and "experiments" not in setup


@pytest.mark.parametrize("path", PLAIN, ids=_id)
def test_imports_without_running(path, capsys):
    name = f"_script_{path.stem}"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    before = list(sys.path)
    try:
        spec.loader.exec_module(mod)  # __name__ is not "__main__": nothing may run
    finally:
        sys.modules.pop(name, None)
    assert sys.path == before, "importing the script changed sys.path"
    assert callable(getattr(mod, "main", None)), "no main()"
    out = capsys.readouterr()
    assert out.out == "" and out.err == "", "the script ran something when imported"
    assert (mod.__doc__ or "").strip(), "no docstring (it is the --help text)"


def _imports(tree: ast.AST) -> list[tuple[int, str]]:
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, f"line {node.lineno}: relative import"
            found.append((node.lineno, node.module))
    return found


@pytest.mark.parametrize("path", PLAIN, ids=_id)
def test_public_imports_only(path):
    tree = ast.parse(path.read_text(), str(path))
    stems = {p.stem for p in SCRIPTS}
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr == "path":
            v = node.value
            assert not (isinstance(v, ast.Name) and v.id == "sys"), f"line {node.lineno}: sys.path"
        if isinstance(node, ast.Name):
            assert node.id != "__import__", f"line {node.lineno}: __import__"
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            assert "PYTHONPATH" not in node.value, f"line {node.lineno}: PYTHONPATH"
    for line, module in _imports(tree):
        top = module.split(".")[0]
        assert top not in stems, f"line {line}: imports the script {top!r}"
        assert top not in ("importlib", "runpy"), f"line {line}: loads code by path ({module})"
        if top in sys.stdlib_module_names or top in PROJECT:
            continue
        spec = importlib.util.find_spec(top)  # an installed library
        assert spec is not None, f"line {line}: {module} is not installed"
        origin = Path(spec.origin or next(iter(spec.submodule_search_locations or []), "")).resolve()
        for folder in FOLDERS:
            assert REPO / folder not in origin.parents, f"line {line}: {module} comes from {folder}/"


def _bad_calls(tree: ast.AST) -> list[str]:
    """Calls of a project function or class (imported by name) whose arguments its signature
    does not take: what an import alone misses when a parameter goes."""
    names = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module.split(".")[0] in PROJECT:
            names.update({a.asname or a.name: (node.module, a.name) for a in node.names})
    bad = []
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in names):
            continue
        module, attr = names[node.func.id]
        obj = getattr(importlib.import_module(module), attr)
        if any(isinstance(a, ast.Starred) for a in node.args) or any(k.arg is None for k in node.keywords):
            continue  # *args / **kwargs: what they hold is not in the source
        try:
            inspect.signature(obj).bind(*node.args, **{k.arg: k.value for k in node.keywords})
        except TypeError as e:
            bad.append(f"line {node.lineno}: {node.func.id}(...): {e}")
    return bad


@pytest.mark.parametrize("path", PLAIN, ids=_id)
def test_calls_fit_the_project_signatures(path):
    """Each script's calls into the project still fit (issue: the inference switches went from
    OnnxInbetweener's constructor and three experiments broke with every import still fine)."""
    assert not _bad_calls(ast.parse(path.read_text(), str(path)))


def test_bad_call_check_finds_a_removed_parameter():
    tree = ast.parse(
        "from pipeline.infer.generator_onnx import OnnxInbetweener\n"
        "OnnxInbetweener('models/default', feet=False)\n"
    )
    assert _bad_calls(tree) == ["line 2: OnnxInbetweener(...): got an unexpected keyword argument 'feet'"]


def test_experiment_settings_are_the_fills_own():
    """The foot-lock and window experiments set attributes the fill reads, not new ones."""
    from pipeline.infer.generator_onnx import OnnxInbetweener

    mods = {}
    for stem in ("foot_lock_variants", "pad_layouts"):
        spec = importlib.util.spec_from_file_location(f"_script_{stem}", REPO / "experiments" / f"{stem}.py")
        mods[stem] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mods[stem])
    model = str(REPO / "models" / "default")
    made = [mods["foot_lock_variants"].inbetweener(model, s) for _, s in mods["foot_lock_variants"].VARIANTS]
    made += [mods["pad_layouts"].inbetweener(model, t, m) for t, m in mods["pad_layouts"].WINDOWS]
    plain = set(vars(OnnxInbetweener(model)))
    for inb in made:
        assert all(n in plain or hasattr(OnnxInbetweener, n) for n in vars(inb)), sorted(
            set(vars(inb)) - plain
        )
    assert {(m.pad_tail, m.min_window) for m in made[-5:]} == set(mods["pad_layouts"].WINDOWS)
    assert not made[0].feet and (made[1].feet_anchor, made[1].feet_orient) == (True, False)


@pytest.mark.parametrize("path", SCRIPTS, ids=_id)
def test_help_exits_0(path, tmp_path, monkeypatch, capsys):
    # In this process (a Python start-up per script cost most of this file's time); run from
    # elsewhere, so nothing depends on the working directory. The -P run of ratio_rows below
    # checks a script as a command, with only installed modules on the path.
    name = f"_script_{path.stem}"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(mod)
        monkeypatch.chdir(tmp_path)
        monkeypatch.setattr(sys, "argv", [str(path), "--help"])
        with pytest.raises(SystemExit) as e:
            mod.main()
    finally:
        sys.modules.pop(name, None)
    out = capsys.readouterr()
    assert e.value.code == 0, out.err[-2000:]
    assert out.out.startswith("usage:") and "-h, --help" in out.out
    assert not list(tmp_path.iterdir()), "--help wrote files"


# --- what moved out of the scripts ----------------------------------------------------


def _rows(scale: float, skate: float = 1.0) -> dict:
    return {
        str(t): {"L2P": scale * t, "L2Q": 2 * scale * t, "NPSS": scale, "skate": skate}
        for t in (5, 15, 30, 45)
    }


def test_bench_ratio_row_divides_the_model_by_interp():
    from pipeline.bench.ratios import bench_ratio_row

    results = {"zero": _rows(9.0), "interp": _rows(2.0, 4.0), "model-v5": _rows(1.0, 1.0)}
    row = bench_ratio_row("v5", results)
    assert (
        row
        == "| v5 | "
        + " | ".join(["0.500 / 0.500 / 0.500 / 0.500"] * 3)
        + " | 0.250 / 0.250 / 0.250 / 0.250 |"
    )
    with pytest.raises(ValueError, match="interp"):
        bench_ratio_row("x", {"model": _rows(1.0)})
    with pytest.raises(ValueError, match="no model row"):
        bench_ratio_row("x", {"interp": _rows(1.0), "zero": _rows(1.0)})


def test_ratio_cells_over_evaluate_results():
    from pipeline.bench.ratios import cell, ratio_cell, ratios

    rows = {5: {"L2P": 1.0}, 15: {"L2P": 3.0}}
    base = {5: {"L2P": 2.0}, 15: {"L2P": 4.0}}
    assert ratios(rows, base, "L2P") == {5: 0.5, 15: 0.75}
    assert ratio_cell(rows, base, "L2P") == "0.500 / 0.750"
    assert cell([1 / 3, 2], digits=2) == "0.33 / 2.00"


def test_ratio_rows_script_prints_the_card_row(tmp_path):
    import json

    f = tmp_path / "bench.json"
    f.write_text(json.dumps({"results": {"interp": _rows(2.0, 4.0), "m": _rows(1.0)}}))
    r = subprocess.run(
        [sys.executable, "-P", str(REPO / "scripts" / "ratio_rows.py"), f"v5={f}"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("| v5 | 0.500 / 0.500") and r.stdout.count("\n") == 1
    bad = subprocess.run(
        [sys.executable, "-P", str(REPO / "scripts" / "ratio_rows.py"), str(f)],
        capture_output=True,
        text=True,
    )
    assert bad.returncode == 2 and "LABEL=PATH" in bad.stderr


def test_train_windows_refuses_no_clips():
    from pipeline.bench.selection import train_windows

    with pytest.raises(ValueError, match="every=0"):
        train_windows(0)
