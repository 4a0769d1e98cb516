"""What a bench's ``python -m`` entry point does with its report: print its Markdown with the
total time, and with ``--out`` write ``NAME.json`` and ``NAME.md`` to that folder."""

from __future__ import annotations

import json
from pathlib import Path

from pipeline.bench.outputs import write_outputs


def publish(report: dict, out: Path | None, name: str) -> None:
    """``report`` holds ``markdown`` and ``seconds``; JSON values it cannot write become text."""
    md = report["markdown"] + f"\nTotal: {report['seconds']:.0f} s.\n"
    if out:
        text = json.dumps(report, indent=1, default=str)
        write_outputs(out, {f"{name}.json": text, f"{name}.md": md})
    print(md)
