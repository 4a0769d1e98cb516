"""Regenerate the TweenAPI plugin files from ``tween/schema.usda`` (needs jinja2).

``python -m usd_schemas.generate`` runs usd-core's own ``usdGenSchema`` and replaces the
CMake placeholders it leaves in plugInfo.json, which a codeless schema does not need.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent / "tween"


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):
        """One line and exit status 2, as every command of the project refuses."""
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def main(argv: list[str] | None = None) -> None:
    # No options; a parser so that --help (or a stray argument) says so instead of rewriting the files.
    _Parser(prog="python -m usd_schemas.generate", description=__doc__.split("\n")[0]).parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(
            [sys.executable, "-m", "pxr.Usd.usdGenSchema", str(HERE / "schema.usda"), tmp], check=True
        )
        text = (Path(tmp) / "plugInfo.json").read_text()
        body = json.loads("\n".join(line for line in text.splitlines() if not line.startswith("#")))
        for plug in body["Plugins"]:
            plug.pop("LibraryPath", None)
            plug.update({"ResourcePath": ".", "Root": "."})
        out = HERE / "resources"
        out.mkdir(exist_ok=True)
        (out / "plugInfo.json").write_text(json.dumps(body, indent=2) + "\n")
        (out / "generatedSchema.usda").write_text((Path(tmp) / "generatedSchema.usda").read_text())
    TOKENS.write_text(tokens_source())
    print(out)


TOKENS = Path(__file__).resolve().parent / "tokens.py"


def _attributes() -> list[str]:
    """Every TweenAPI property name, in schema order (their docs are the schema's)."""
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(str(HERE / "schema.usda"))
    return [p.name for p in layer.GetPrimAtPath("/TweenAPI").properties]


def tokens_source() -> str:
    """The text of tokens.py: a constant per schema attribute (``tween:keyTimes`` ->
    ``KEY_TIMES``), the schema's name and the take variant set."""

    lines = [
        '"""Every ``tween:*`` name the project authors or reads, generated from ``tween/schema.usda``',
        "by ``python -m usd_schemas.generate`` (do not edit by hand; a test checks it is current).",
        '"""',
        "",
        'API = "TweenAPI"  # the applied API schema',
        'TAKE_VARIANT_SET = "tweenTake"  # the variant set holding the takes of a fill',
    ]
    for name in _attributes():
        const = re.sub(r"(?<!^)(?=[A-Z])", "_", name.split(":", 1)[1]).upper()
        lines.append(f'{const} = "{name}"')
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
