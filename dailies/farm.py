"""The farm's fill jobs for the shots under the roots (queued, running stage, failed with
reason, cancelled), and cancelling one, through :mod:`workers.jobs`.

The farm keeps a job's record in its result backend under the job id (``workers.jobs.submit``)
and has no index by shot, so the records are found there: a key scan on Redis, a query on a
database backend. Without a farm configured (no broker: each ``tween fill`` runs its own
embedded one, whose jobs end with it) there is nothing to list, and the page says so.
"""

from __future__ import annotations

import glob
import os
import re
import time
from pathlib import Path

from pipeline.errors import TweenError
from workers.settings import redact_url

#: A fill job's id (``uuid4().hex``); stages and control records have dotted ids after it.
JOB_ID = re.compile(r"[0-9a-f]{32}")
#: Most jobs shown (newest first): a page, not an archive.
LIMIT = 100
#: Seconds a cancel waits for a running stage to stop before answering "cancelling".
SETTLE_S = 10.0


def _farm():
    from workers.app import SETTINGS_ERROR
    from workers.app import app as celery_app

    if SETTINGS_ERROR is not None:
        raise SETTINGS_ERROR
    return celery_app


def _job_ids(backend) -> list[str] | None:
    """Every fill job id the result backend holds; None for a backend that cannot be listed."""
    if hasattr(backend, "client") and hasattr(backend, "get_key_for_task"):  # Redis
        pattern = backend.get_key_for_task("*")
        head = len(pattern) - 1
        return [k[head:].decode() for k in backend.client.scan_iter(match=pattern, count=1000)
                if JOB_ID.fullmatch(k[head:].decode(errors="replace"))]  # fmt: skip
    if hasattr(backend, "ResultSession"):  # SQLAlchemy: the database backends
        from celery.backends.database.models import Task

        from workers.app import SUBMITTED

        session = backend.ResultSession()
        try:
            rows = session.query(Task.task_id).filter(Task.status == SUBMITTED).all()
        finally:
            session.close()
        return [r[0] for r in rows if JOB_ID.fullmatch(r[0])]
    return None


def _under(path: str, roots: list[Path]) -> bool:
    real = Path(os.path.realpath(path))
    return any(real.is_relative_to(os.path.realpath(r)) for r in roots)


def _row(js) -> dict:
    rec = js.record or {}
    return {**js.as_dict(), "submitted": rec.get("time"), "takes": rec.get("takes"),
            "render": rec.get("render"), "cancel": js.cancel, "lost": js.lost}  # fmt: skip


def listing(roots: list[Path], shot_folder: Path | None = None, stem: str | None = None) -> dict:
    """{"farm", "jobs": [...], "note"}: the unfinished, failed and cancelled jobs of shots under
    ``roots`` (of one shot with ``shot_folder``/``stem``), newest first; a farm that is not
    configured or does not answer is a ``note``, not an error."""
    from workers.app import check_farm, farm_errors

    try:
        celery_app = _farm()
    except TweenError as e:
        return {"farm": None, "jobs": [], "note": str(e)}
    s = celery_app.conf.tween
    if s.embedded:
        return {"farm": None, "jobs": [],
                "note": "no farm configured (TWEEN_BROKER_URL): each tween fill runs its own, and its jobs end with it"}  # fmt: skip
    import workers.jobs as jobs

    farm = redact_url(s.result_backend or s.broker_url)
    try:
        check_farm(celery_app, broker=False)
        with farm_errors(celery_app):
            ids = _job_ids(celery_app.backend)
            if ids is None:
                return {"farm": farm, "jobs": [], "note": "this farm's result backend cannot list its jobs"}
            metas = [(j, celery_app.backend.get_task_meta(j)) for j in ids]
            recs = [
                (j, m["result"])
                for j, m in metas
                if isinstance(m.get("result"), dict) and m["result"].get("shot")
            ]
            recs = [(j, r) for j, r in recs if _under(r["shot"], roots)]
            if stem is not None:
                recs = [(j, r) for j, r in recs if Path(r["shot"]).name.split(".")[0] == stem
                        and os.path.realpath(r.get("out_dir") or os.path.dirname(r["shot"]))
                        == os.path.realpath(shot_folder)]  # fmt: skip
            recs.sort(key=lambda jr: -float(jr[1].get("time") or 0))
            rows = [_row(js) for js in (jobs.state(j) for j, _ in recs[:LIMIT]) if js.state != "SUCCESS"]
    except TweenError as e:
        return {"farm": farm, "jobs": [], "note": str(e)}
    return {"farm": farm, "jobs": rows, "note": None}


def cancel(roots: list[Path], job_id: str) -> dict:
    """Cancels a fill job of a shot under the roots (``tween cancel``'s pieces): its cancel
    record, then, once no stage runs (at most ``SETTLE_S``), what it wrote removed."""
    import workers.jobs as jobs
    from workers.app import check_farm, farm_errors

    celery_app = _farm()
    if celery_app.conf.tween.embedded:
        raise TweenError("no farm configured (TWEEN_BROKER_URL): nothing to cancel here")
    if not JOB_ID.fullmatch(job_id):
        raise LookupError(job_id)
    check_farm(celery_app, broker=False)
    with farm_errors(celery_app):
        js = jobs.state(job_id)
        if js.state == "UNKNOWN" or not _under(js.shot, roots):
            raise LookupError(job_id)
        if js.finished:
            raise TweenError(f"job {job_id} {js.shot}: already {js.state.lower()}, nothing to cancel")
        jobs.cancel([job_id], why="tween dailies")
        t0 = time.monotonic()
        while True:
            js = jobs.state(job_id)
            if js.finished or time.monotonic() - t0 > SETTLE_S:
                break
            time.sleep(0.2)
        jobs.undo_cancelled(js)
    return _row(js)


def render(roots: list[Path], shot, version: int, unrendered: list[int]) -> dict:
    """Submits the render-only job of ``shot``'s fill ``version`` (its takes ``unrendered``
    have no media yet): the page's "render". Refused when the version is rendered, when a
    render of it is already on the farm, or without a farm."""
    import workers.jobs as jobs
    from workers.app import check_farm, farm_errors

    if not unrendered:
        raise TweenError(f"{shot.stem} v{version:03d}: every take is rendered already")
    review = sorted(shot.folder.glob(f"{glob.escape(shot.stem)}.review.v{version:03d}.usd*"))
    if not review:
        raise TweenError(
            f"{shot.stem} v{version:03d}: its review layer is gone; fill the shot again to render it"
        )
    celery_app = _farm()
    if celery_app.conf.tween.embedded:
        raise TweenError(
            "no farm configured (TWEEN_BROKER_URL): render it here with "
            f"tween review {review[0]} --all-takes --out {shot.folder / 'review'}"
        )
    check_farm(celery_app)
    with farm_errors(celery_app):
        ids = _job_ids(celery_app.backend) or []
        for j in ids:
            rec = celery_app.backend.get_task_meta(j).get("result")
            if isinstance(rec, dict) and rec.get("kind") == "review" and rec.get("review") == str(review[0]):
                js = jobs.state(j)
                if not js.finished:
                    raise TweenError(
                        f"{shot.stem} v{version:03d}: already rendering, job {j} ({js.state.lower()})"
                    )
        job_id = jobs.submit_review(str(review[0]), roots=[str(r) for r in roots])
        return _row(jobs.state(job_id))
