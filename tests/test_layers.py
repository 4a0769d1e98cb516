"""The architecture of the README, as a test: packages import only downward.

Read from the code's own imports (module level and inside functions alike), by AST.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Layer of each package, bottom up; a package imports only packages on lower layers.
LAYERS = {
    "pipeline.errors": 0,
    "usd_schemas": 0,
    "pipeline.options": 0,  # options declared on dataclasses, as CLI options
    "pipeline.jsonfile": 0,  # JSON a person wrote: duplicate keys refused
    "pipeline.atomic": 0,  # a file replaced whole or not at all
    "pipeline.inputs": 0,  # what a command reads: a regular file, or what the path is instead
    "pipeline.arguments": 1,  # argparse whose errors are one line (the python -m entry points)
    "pipeline.progress": 0,  # how often a progress bar redraws (a terminal, a log file)
    "pipeline.outputs": 1,  # where a command writes, checked before it writes (read-only, links)
    "pipeline.staging": 2,  # model folders made beside their destination, moved in when complete
    "pipeline.command": 1,  # the one error handler every entry point runs its commands through
    "pipeline.motion": 1,  # skeletons, clips, rotations, FK, BVH
    "pipeline.data": 2,  # the split, clip caches, the model skeleton, the protocol's windows
    "pipeline.infer": 3,  # in-betweeners at fill time: numpy + onnxruntime, never torch
    "pipeline.adapt": 3,  # rig adaptation on plain rig values: mapping, retargeting (no USD)
    "pipeline.usd": 4,  # USD I/O (beside the in-betweeners; the rest pose of a converted rig)
    "pipeline.networks": 5,  # the torch networks
    "pipeline.rig": 5,  # per-rig models: their training, ONNX in-betweener and store
    "pipeline.library": 5,  # a studio's motion library: its store, build and in-betweener
    "pipeline.train": 6,  # training and export of the networks
    "pipeline.fill": 7,  # fill orchestration above USD I/O, adaptation and every model
    "pipeline.bench": 8,
    "render": 8,  # reads composed USD only
    "workers": 9,  # the farm: runs the fill API and the renderer
    "pipeline.cli": 10,  # the CLI on top; its commands come from entry points
    "dailies": 10,  # the review page in the browser: over the farm, the renderer and the dailies step
    "pipeline.entry": 11,  # the executable's first module: signals while the CLI loads
}
#: Modules allowed one import across their layer's rule, and why.
EXCEPTIONS = {
    ("render.bench", "pipeline.fill"): "the render benchmark fills its own shot before timing the review",
    (
        "render.bench",
        "pipeline.command",
    ): "its python -m entry refuses bad arguments as tween does (run_main)",
}
HEAVY_FOR_INFER = ("torch", "roma")


def _package(module: str) -> str:
    parts = module.split(".")
    if parts[0] == "pipeline" and len(parts) > 1:
        return ".".join(parts[:2])
    return parts[0]


def _modules():
    for top in ("pipeline", "workers", "render", "usd_schemas", "dailies"):
        for path in sorted((ROOT / top).rglob("*.py")):
            mod = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
            yield mod, path


def _imports(path: Path):
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, node.lineno
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            yield node.module, node.lineno
            if node.module == "pipeline":  # from pipeline import fill
                for a in node.names:
                    yield f"pipeline.{a.name}", node.lineno


def _project_edges():
    for mod, path in _modules():
        for name, line in _imports(path):
            if (
                name.split(".")[0] in ("pipeline", "workers", "render", "usd_schemas", "dailies")
                and name != "pipeline"
            ):
                yield mod, _package(mod), _package(name), f"{path.relative_to(ROOT)}:{line} imports {name}"


def test_every_package_has_a_layer():
    missing = {_package(m) for m, _ in _modules()} - set(LAYERS) - {"pipeline"}
    assert not missing, f"packages without a layer in tests/test_layers.py: {sorted(missing)}"


def test_imports_only_run_downward():
    bad = []
    for mod, src, dst, where in _project_edges():
        if src == dst or (mod, dst) in EXCEPTIONS or src == "pipeline":
            continue
        if LAYERS[dst] >= LAYERS[src]:
            bad.append(f"{where} ({src}, layer {LAYERS[src]} -> {dst}, layer {LAYERS[dst]})")
    assert not bad, "imports that do not run downward:\n" + "\n".join(bad)


def test_no_package_cycles():
    graph: dict[str, set[str]] = {}
    for _, src, dst, _ in _project_edges():
        if src != dst:
            graph.setdefault(src, set()).add(dst)

    def reach(a, seen):
        for b in graph.get(a, ()):
            if b not in seen:
                seen.add(b)
                reach(b, seen)
        return seen

    cycles = [p for p in graph if p in reach(p, set())]
    assert not cycles, f"packages in an import cycle: {cycles}"


@pytest.mark.parametrize("package", ["pipeline.infer", "pipeline.adapt", "pipeline.usd", "pipeline.fill"])
def test_fill_time_packages_never_import_torch(package):
    hits = [f"{p.relative_to(ROOT)}:{ln} imports {n}" for m, p in _modules() if _package(m) == package
            for n, ln in _imports(p) if n.split(".")[0] in HEAVY_FOR_INFER]  # fmt: skip
    assert not hits, hits


def test_rig_adaptation_has_no_usd_in_it():
    hits = [f"{p.relative_to(ROOT)}:{ln} imports {n}" for m, p in _modules() if _package(m) == "pipeline.adapt"
            for n, ln in _imports(p) if n.split(".")[0] == "pxr" or _package(n) == "pipeline.usd"]  # fmt: skip
    assert not hits, hits


def test_render_reads_composed_usd_only():
    """The renderer reads USD (and the shared character reader), never the fill or a model."""
    allowed = {"pipeline.errors", "pipeline.motion", "pipeline.data", "pipeline.usd", "render", "usd_schemas",
               "pipeline.progress", "pipeline.arguments", "pipeline.outputs"}  # fmt: skip
    hits = [where for mod, src, dst, where in _project_edges()
            if src == "render" and dst not in allowed and (mod, dst) not in EXCEPTIONS]  # fmt: skip
    assert not hits, hits


def test_core_cli_imports_neither_farm_nor_renderer():
    names = {n for n, _ in _imports(ROOT / "pipeline" / "cli.py")}
    assert not {n for n in names if n.split(".")[0] in ("workers", "render")}, names


def test_the_cli_starts_without_the_farm_or_the_solvers():
    """Every `tween` call (a refusal, --help, a completion) pays the CLI's start-up: the farm's
    client (Celery, kombu, SQLAlchemy), scipy, onnxruntime and torch are imported by the
    commands that use them, not by the CLI's registration (was 1.1 s, now about 0.5 s)."""
    import subprocess
    import sys

    code = (
        "import sys, pipeline.cli as c\n"
        "try: c.main(['fill', '--help'])\n"
        "except SystemExit: pass\n"
        "heavy = ('celery', 'kombu', 'sqlalchemy', 'redis', 'scipy', 'onnxruntime', 'torch', 'moderngl', 'av')\n"
        "print(' '.join(m for m in heavy if m in sys.modules), file=sys.stderr)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stderr.strip() == "", r.stderr[-2000:]


#: Libraries worth deferring to the function that needs them: torch and its helpers (training),
#: USD, onnxruntime, GL and the media libraries (render), the farm's (slow to import, absent
#: on a host that only fills), scipy (a quarter second, off the CLI's start-up path).
DEFERRED = {"torch", "roma", "onnx", "onnxscript", "pxr", "onnxruntime", "moderngl", "OpenImageIO", "av",
            "opentimelineio", "celery", "kombu", "redis", "amqp", "sqlalchemy", "billiard", "scipy", "bpy",
            "threadpoolctl", "jinja2", "fastapi", "starlette", "uvicorn", "httpx", "gazu"}  # fmt: skip


def _top_imports(path: Path) -> list[str]:
    out = []
    for node in ast.parse(path.read_text()).body:
        for n in ast.walk(node) if isinstance(node, (ast.If, ast.Try)) else [node]:
            if isinstance(n, ast.Import):
                out += [a.name for a in n.names]
            elif isinstance(n, ast.ImportFrom) and n.module and not n.level:
                out += [n.module] + [f"{n.module}.{a.name}" for a in n.names]
    return out


def _pulls_deferred(module: str, modules: dict, seen: set) -> bool:
    """Whether importing ``module`` imports a DEFERRED library (through its own module-level
    imports, its packages' and theirs; pipeline.usd registers the USD plugin on import)."""
    if module in seen or module not in modules:
        return False
    seen.add(module)
    if module == "pipeline.usd":
        return True
    parts = module.split(".")
    names = _top_imports(modules[module]) + [".".join(parts[:i]) for i in range(1, len(parts))]
    for n in names:
        if n.split(".")[0] in DEFERRED:
            return True
        target = next((c for c in (".".join(n.split(".")[:i]) for i in range(len(n.split(".")), 0, -1))
                       if c in modules), None)  # fmt: skip
        if target and _pulls_deferred(target, modules, seen):
            return True
    return False


#: Function-local imports of light modules allowed all the same, and why.
LOCAL_IMPORTS = {
    ("pipeline.entry", "pipeline.cli"): "the executable's signal handlers are set before the CLI's imports",
}


def test_function_local_imports_only_defer_heavy_libraries():
    modules = dict(_modules())
    bad = []
    for mod, path in modules.items():
        tree = ast.parse(path.read_text())
        for fn in ast.walk(tree):
            if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            optional = {id(n) for t in ast.walk(fn) if isinstance(t, ast.Try)
                        and any("ImportError" in ast.dump(h) for h in t.handlers) for n in ast.walk(t)}  # fmt: skip
            for node in ast.walk(fn):
                if not isinstance(node, ast.Import | ast.ImportFrom) or id(node) in optional:
                    continue
                name = node.module if isinstance(node, ast.ImportFrom) else node.names[0].name
                if not name or getattr(node, "level", 0) or name.split(".")[0] in DEFERRED:
                    continue
                target = next((c for c in (".".join(name.split(".")[:i]) for i in range(len(name.split(".")), 0, -1))
                               if c in modules), None)  # fmt: skip
                if target is not None and (target == mod or _pulls_deferred(target, modules, set())):
                    continue
                if (mod, name) in LOCAL_IMPORTS:
                    continue
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno} imports {name} inside {fn.name}()")
    assert not bad, "function-local imports that defer nothing heavy:\n" + "\n".join(bad)
