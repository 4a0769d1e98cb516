"""The fill's JSON (``tween status --json``'s result, ``tween fill-local``'s output) as the
panel uses it: the layers, each take, and the trusted fill's decision (no ``bpy``)."""

from __future__ import annotations

import os
from dataclasses import dataclass, field


@dataclass
class Take:
    index: int
    decision: str  # "model", "spline", "blend 0.60" (the model's weight), or "" when not told
    mp4: str | None = None
    contact_sheet: str | None = None
    timeline: str | None = None
    same_as: int | None = None  # a take identical to an earlier one (a spline fill has no seed)


@dataclass
class FillResult:
    layer: str
    review: str | None
    version: int
    model: str
    takes: list[Take] = field(default_factory=list)
    reason: str = ""  # why the trusted fill decided as it did (the first character's)

    @property
    def timeline(self) -> str | None:
        return next((t.timeline for t in self.takes if t.timeline), None)


def decision(trust: dict | None) -> str:
    """``model``, ``spline`` or ``blend 0.60`` (the model's weight) from a trust decision."""
    if not trust:
        return ""
    choice = str(trust.get("choice") or "")
    if choice == "blend":
        return f"blend {float(trust.get('weight') or 0.0):.2f}"
    return choice


def read_result(d: dict, base: str = "") -> FillResult:
    """The fill's JSON; relative paths are read against ``base``. Raises ValueError (one
    line) when it names no layer."""
    if not isinstance(d, dict) or not d.get("layer"):
        raise ValueError("the fill's result names no layer")

    def path(p):
        return os.path.normpath(os.path.join(base, p)) if p and base else p

    trust = d.get("trust") or {}
    first = next((v for v in trust.values() if v), None) if isinstance(trust, dict) else None
    dec = decision(first)
    n = int(d.get("takes") or 1)
    renders = d.get("renders") or []
    same = {int(k): int(v) for k, v in (d.get("same_as") or {}).items()}
    takes = []
    for i in range(n):
        r = renders[i] if i < len(renders) and isinstance(renders[i], dict) else {}
        takes.append(
            Take(
                i, dec, path(r.get("mp4")), path(r.get("contact_sheet")), path(r.get("timeline")), same.get(i)
            )
        )
    return FillResult(
        layer=path(d["layer"]),
        review=path(d.get("review")),
        version=int(d.get("version") or 0),
        model=str(d.get("model") or ""),
        takes=takes,
        reason=str((first or {}).get("reason") or ""),
    )
