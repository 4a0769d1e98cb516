"""``tween status --json`` as the panel shows it (no ``bpy``)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field

FINISHED = ("SUCCESS", "FAILURE", "UNKNOWN", "CANCELLED")


@dataclass
class JobStatus:
    id: str
    state: str = "QUEUED"  # QUEUED, RUNNING, SUCCESS, FAILURE, CANCELLING, CANCELLED, UNKNOWN
    done: int = 0
    total: int = 0
    stage: str = ""
    error: str | None = None
    result: dict = field(default_factory=dict)

    @property
    def finished(self) -> bool:
        return self.state in FINISHED

    @property
    def fraction(self) -> float:
        if self.state == "SUCCESS":
            return 1.0
        return self.done / self.total if self.total else 0.0

    def text(self) -> str:
        """``running take1 (2/5 stages)``, ``done``, ``failed: why``."""
        if self.state == "SUCCESS":
            return "done"
        if self.state in ("FAILURE", "UNKNOWN", "CANCELLED"):
            return f"{self.state.lower()}: {self.error or 'no reason given'}"
        what = self.state.lower() + (f" {self.stage}" if self.stage else "")
        return f"{what} ({self.done}/{self.total} stages)" if self.total else what


def parse_status(stdout: str, job_id: str) -> JobStatus:
    """The job's state from ``tween status --json`` output (one JSON object a line; other
    lines ignored). Raises ValueError (one line) when there is none for ``job_id``."""
    for ln in stdout.splitlines():
        ln = ln.strip()
        if not ln.startswith("{"):
            continue
        try:
            d = json.loads(ln)
        except ValueError:
            continue
        if not isinstance(d, dict) or d.get("id") != job_id:
            continue
        return JobStatus(
            id=job_id,
            state=str(d.get("state") or "UNKNOWN"),
            done=int(d.get("done") or 0),
            total=int(d.get("total") or 0),
            stage=str(d.get("stage") or ""),
            error=d.get("error"),
            result=d.get("result") if isinstance(d.get("result"), dict) else {},
        )
    raise ValueError(f"tween status said nothing about job {job_id}")
