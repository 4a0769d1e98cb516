"""Every path in a job must lie under a configured shot root, after resolving symlinks.

Workers write layers next to shots on shared storage; a job that names ``../../etc`` or a
symlink pointing out of the show tree is refused before any work, on the submitting host
and again on the worker (the worker's own roots are the ones that count).
"""

from __future__ import annotations

import os
from collections.abc import Iterable

from pipeline.errors import TweenError
from pipeline.fill.options import PATH_FIELDS


class PathRefused(TweenError):
    """A job path lies outside the shot roots."""


def resolve_roots(roots: Iterable[str]) -> list[str]:
    return [os.path.realpath(os.path.expanduser(r)) for r in roots if r]


def check_under_roots(path: str, roots: Iterable[str], what: str = "path") -> str:
    """Returns the resolved ``path`` if it lies inside one of ``roots``; raises :class:`PathRefused`."""
    resolved_roots = resolve_roots(roots)
    if not resolved_roots:
        raise PathRefused(f"{path}: refused, no shot roots are configured (set TWEEN_SHOT_ROOTS)")
    real = os.path.realpath(os.path.expanduser(path))
    for root in resolved_roots:
        if os.path.commonpath([real, root]) == root:
            return real
    raise PathRefused(
        f"{path}: refused, {what} resolves to {real}, outside the shot roots ({os.pathsep.join(resolved_roots)})"
    )


def check_takes_under_roots(folder: str, roots: Iterable[str]) -> None:
    """Every take a library build would read under ``folder`` resolves inside ``roots``: the
    folder may lie inside them and still link to takes elsewhere (a linked folder or file)."""
    from pipeline.usd.take import take_files

    for take in take_files(folder):
        check_under_roots(str(take), roots, "take")


def job_paths(shot: str, opts: dict, work_dir: str | None = None) -> dict[str, str]:
    """The paths a job reads or writes, by role."""
    paths = {"shot": shot}

    for key in PATH_FIELDS:
        if opts.get(key):
            paths[key] = opts[key]
    if work_dir:
        paths["work_dir"] = work_dir
    return paths


def check_job(shot: str, opts: dict, roots: Iterable[str], work_dir: str | None = None) -> None:
    roots = list(roots)
    for role, p in job_paths(shot, opts, work_dir).items():
        check_under_roots(p, roots, role)
