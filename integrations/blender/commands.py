"""The ``tween`` command lines the extension runs, and what their output means (no ``bpy``).

The extension never imports usd-tween: it runs the configured ``tween`` executable as a
subprocess (``tween fill`` on an embedded farm, ``tween submit`` to a broker), and reads its
stdout/stderr. A CLI failure becomes one line (:func:`error_line`) for Blender's report.
"""

from __future__ import annotations

import os
import re
import shutil
from dataclasses import dataclass

FARMS = ("EMBEDDED", "FARM")
TRUST = ("auto", "model", "spline")
MAX_TAKES = 64  # as `tween fill --takes`
_ID = re.compile(r"^[0-9a-f]{32}$")
# `tween fill` says the job id as it submits (workers/cli.py), so its state can be polled.
_SUBMITTED = re.compile(r"^tween: job ([0-9a-f]{32}) submitted\b")
_ERROR_SHOWN = 400  # characters of one report line


@dataclass
class Settings:
    """The add-on preferences, as plain values."""

    tween: str = "tween"  # the executable (a path, or a name on PATH)
    farm: str = "EMBEDDED"  # EMBEDDED: `tween fill` starts its own worker; FARM: `tween submit`
    broker_url: str = ""  # FARM: TWEEN_BROKER_URL (empty: the farm config file's)
    out_dir: str = ""  # where the blocking exports and the fill layers go
    model: str = "default"
    takes: int = 3
    trust: str = "auto"
    render: bool = False  # render each take's review (MP4, contact sheet, timeline) on the farm
    mapping: str = ""  # a --mapping JSON file, for a rig whose joints do not map by themselves


def executable(s: Settings) -> str | None:
    """The tween executable's full path, or None when there is none."""
    exe = os.path.expanduser(s.tween.strip())
    if not exe:
        return None
    if os.sep in exe:
        return exe if os.path.isfile(exe) and os.access(exe, os.X_OK) else None
    return shutil.which(exe)


def check(s: Settings) -> str | None:
    """What is wrong with the settings, as one line, or None."""
    if executable(s) is None:
        return f"tween executable {s.tween!r} not found: set it in the usd-tween add-on preferences"
    if s.farm not in FARMS:
        return f"farm {s.farm!r}: one of {', '.join(FARMS)}"
    if s.trust not in TRUST:
        return f"trust {s.trust!r}: one of {', '.join(TRUST)}"
    if not 1 <= int(s.takes) <= MAX_TAKES:
        return f"takes {s.takes}: from 1 to {MAX_TAKES}"
    if not s.model.strip():
        return "model: empty (default is the stored model for the rig, else the human model)"
    if not s.out_dir.strip():
        return "output folder: not set (add-on preferences)"
    if s.mapping.strip() and not os.path.isfile(os.path.expanduser(s.mapping.strip())):
        return f"mapping file {s.mapping.strip()!r}: no such file"
    return None


def fill_command(s: Settings, shot: str, out_dir: str) -> list[str]:
    """``tween fill`` (embedded: waits, says the job id as it submits) or ``tween submit``
    (farm: prints the job id and returns)."""
    verb = "fill" if s.farm == "EMBEDDED" else "submit"
    cmd = [executable(s) or s.tween, verb, shot, "--out-dir", out_dir, "--takes", str(int(s.takes))]
    cmd += ["--model", s.model.strip(), "--trust", s.trust, "--format", "usda"]  # usda: read back as text
    # `tween fill` waits; with its progress on (the default) it says each job id as it submits
    if s.render:
        cmd.append("--render")
    if s.mapping.strip():
        cmd += ["--mapping", os.path.expanduser(s.mapping.strip())]
    return cmd


def status_command(s: Settings, job_id: str) -> list[str]:
    return [executable(s) or s.tween, "status", "--json", job_id]


def approve_command(s: Settings, shot: str, out_dir: str, take: int, note: str = "") -> list[str]:
    cmd = [executable(s) or s.tween, "approve", shot, "--take", str(int(take)), "--out-dir", out_dir]
    note = " ".join(note.split())  # one line, as the dailies page keeps it
    return cmd + (["--note", note] if note else [])


def publish_command(s: Settings, shot: str, out_dir: str) -> list[str]:
    return [executable(s) or s.tween, "publish", shot, "--out-dir", out_dir]


def review_command(s: Settings, review: str, take: int | None, out: str) -> list[str]:
    """``tween review`` of one take (None: a fill of one take has no variant to select)."""
    cmd = [executable(s) or s.tween, "review", review, "--no-frames", "-o", out]
    return cmd + (["--take", str(int(take))] if take is not None else [])


def environment(s: Settings, base: dict | None = None) -> dict[str, str]:
    """The subprocess's environment: the farm's broker (or none, for the embedded farm), and
    nothing of Blender's Python (the tween executable runs its own interpreter)."""
    env = dict(os.environ if base is None else base)
    for k in ("PYTHONHOME", "PYTHONPATH", "PYTHONSTARTUP", "PYTHONNOUSERSITE"):
        env.pop(k, None)
    if s.farm == "EMBEDDED":
        env.pop("TWEEN_BROKER_URL", None)
    elif s.broker_url.strip():
        env["TWEEN_BROKER_URL"] = s.broker_url.strip()
    env.update(PYTHONUNBUFFERED="1", NO_COLOR="1", TERM="dumb", COLUMNS="200")
    return env


def submitted_ids(stdout: str) -> list[str]:
    """The job ids ``tween submit`` printed (one a line)."""
    return [ln.strip() for ln in stdout.splitlines() if _ID.match(ln.strip())]


def submitted_id(stderr: str) -> str | None:
    """The job id ``tween fill`` said when it submitted, once it has."""
    for ln in stderr.splitlines():
        m = _SUBMITTED.match(ln.strip())
        if m:
            return m.group(1)
    return None


def error_line(stderr: str, stdout: str = "", rc: int | None = None) -> str:
    """One line for a failed command: its ``tween: error:`` line, else its last line."""
    lines = [ln.strip() for ln in (stderr or "").splitlines() if ln.strip()]
    errs = [ln for ln in lines if ln.startswith("tween: error:")]
    if errs:
        line = errs[-1][len("tween: error:") :].strip()
    elif lines:
        line = lines[-1]  # a crash's last line names the exception
    else:
        out = [ln.strip() for ln in (stdout or "").splitlines() if ln.strip()]
        line = out[-1] if out else f"tween exited with status {rc}"
    line = " ".join(line.split())
    return line if len(line) <= _ERROR_SHOWN else line[: _ERROR_SHOWN - 1] + "…"


def published_layer(stdout: str) -> str | None:
    """The layer ``tween publish`` wrote (the last path it printed)."""
    for ln in reversed(stdout.splitlines()):
        m = re.search(r"(\S+\.usd[ac]?)\b", ln)
        if m:
            return m.group(1)
    return None
