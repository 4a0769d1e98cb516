"""Regenerate the TweenAPI plugin files from ``tween/schema.usda`` (needs jinja2).

``python -m usd_schemas.generate`` runs usd-core's own ``usdGenSchema`` and replaces the
CMake placeholders it leaves in plugInfo.json, which a codeless schema does not need.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent / "tween"


def main() -> None:
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
    print(out)


if __name__ == "__main__":
    main()
