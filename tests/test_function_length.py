"""Functions a reader can hold (issue 33): none in ``pipeline/``, ``workers/`` or ``render/``
runs over MAX_LINES lines unless the top of its body says why, in a comment starting
``# Long because``. Read by AST: a function's lines run from its ``def`` to its last line."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("pipeline", "workers", "render")
MAX_LINES = 60
REASON = "# Long because"


def _long_functions():
    """(path, name, lines, whether the top of its body gives the reason) of every function
    over MAX_LINES lines."""
    for top in PACKAGES:
        for path in sorted((ROOT / top).rglob("*.py")):
            lines = path.read_text().splitlines()
            for fn in ast.walk(ast.parse("\n".join(lines))):
                if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
                    continue
                length = fn.end_lineno - fn.lineno + 1
                if length <= MAX_LINES:
                    continue
                # The top of the body: from the def to its first statement after the docstring.
                body = fn.body[1:] if ast.get_docstring(fn) is not None and len(fn.body) > 1 else fn.body
                top_lines = lines[fn.lineno - 1 : body[0].lineno - 1]
                given = any(ln.strip().startswith(REASON) for ln in top_lines)
                yield path.relative_to(ROOT).as_posix(), fn.name, length, given


def test_long_functions_say_why():
    bad = [
        f"{path}: {name}() is {length} lines" for path, name, length, given in _long_functions() if not given
    ]
    assert not bad, (
        f"functions over {MAX_LINES} lines: split them into named stages, or say why at the top of "
        f"the body in a comment starting {REASON!r}:\n" + "\n".join(bad)
    )
