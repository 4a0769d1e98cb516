"""Every `tween` command line in the guides' code blocks names a command that exists and options
it takes, and parses as written (placeholders filled in): the docs say what the code does."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
from cli_contract import OPTION, commands, options_of

ROOT = Path(__file__).resolve().parents[1]
DOCS = ["README.md", "docs/farm.md", "docs/render.md", "docs/usd.md", "docs/library.md", "docs/rig.md",
        "docs/dailies.md", "docs/trust.md", "docs/models.md"]  # fmt: skip


def _doc_lines():
    for doc in DOCS:
        text = (ROOT / doc).read_text()
        for block in re.findall(r"```[a-z]*\n(.*?)```", text, re.S):
            joined = re.sub(r"\\\n\s*", " ", block)  # continuation lines
            for line in joined.splitlines():
                line = re.sub(r"^\$ ", "", line.strip())
                if line.startswith("tween "):
                    yield doc, line


LINES = list(_doc_lines())


def _args(line: str) -> list[str]:
    line = re.split(r"\s#\s|\s+#", line, maxsplit=1)[0]  # the comment
    line = re.sub(r"\[[^\]]*\]", " ", line)  # optional parts (their options are checked apart)
    line = re.sub(r"<[^>]*>(\.\.\.)?", "JOB", line).replace("...", "").replace("…", "")
    return shlex.split(line)[1:]


def test_the_guides_hold_tween_command_lines():
    assert len(LINES) > 20


@pytest.mark.parametrize("doc, line", LINES, ids=[f"{d}:{i}" for i, (d, _) in enumerate(LINES)])
def test_a_documented_command_line_parses(doc, line):
    args = _args(line)
    name = f"{args[0]} {args[1]}" if len(args) > 1 and f"{args[0]} {args[1]}" in commands() else args[0]
    assert name in commands(), f"{doc}: `{line}`: no command {name!r}"
    cmd = commands()[name]
    rest = args[len(name.split()) :]
    cmd.make_context(name, rest)  # raises on an option it does not take or a value it cannot read
    optional = " ".join(re.findall(r"\[([^\]]*)\]", re.split(r"\s#", line, maxsplit=1)[0]))
    unknown = [o for o in OPTION.findall(optional) if o not in options_of(name)]
    assert not unknown, f"{doc}: `{line}`: {name} takes no {unknown}"
