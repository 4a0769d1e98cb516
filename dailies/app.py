"""The dailies web app: the review page (``/``, ``/shot/KEY``), its media (``/media``) and the
JSON API that mirrors it (``/api``, schema at ``/api/openapi.json``), all behind the login."""

from __future__ import annotations

from pathlib import Path

from fastapi import Body, FastAPI, HTTPException, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse
from fastapi.staticfiles import StaticFiles
from fastapi.templating import Jinja2Templates
from pydantic import BaseModel, Field, field_validator

from dailies import decide, farm, media
from dailies.auth import Login, LoginMiddleware
from dailies.detail import detail
from dailies.shots import find, listing
from pipeline.errors import TweenError
from pipeline.options import one_line

HERE = Path(__file__).parent


class Approval(BaseModel):
    take: int = Field(ge=0, strict=True, description="The approved take.")
    note: str | None = Field(None, max_length=10000, description="The reviewer's note.")
    by: str | None = Field(
        None, max_length=200, description="The reviewer's name (default: the user the server runs as)."
    )
    version: int | None = Field(
        None, strict=True, description="The fill version the page showed; refused if no longer the latest."
    )

    # The approval's own rules (pipeline.usd.dailies), checked with the schema: a body that
    # breaks them is invalid (422), not a decision the shot's state refuses (409).
    @field_validator("by")
    @classmethod
    def _by_is_one_line(cls, by: str | None) -> str | None:
        if by is not None and not one_line(by):
            raise ValueError("the reviewer's name must be printable, one line, 1 to 200 characters")
        return by

    @field_validator("note")
    @classmethod
    def _note_has_no_nul(cls, note: str | None) -> str | None:
        if note is not None and "\0" in note:
            raise ValueError("the note must not hold a NUL character")
        return note


class Publication(BaseModel):
    version: int | None = Field(None, strict=True, description="The fill version the page showed.")


def _with_urls(roots: list[Path], d: dict) -> dict:
    for t in d["takes"]:
        t["mp4_url"] = media.url(roots, t["mp4"])
        t["contact_sheet_url"] = media.url(roots, t["contact_sheet"])
        t["mp4"] = str(t["mp4"]) if t["mp4"] else None
        t["contact_sheet"] = str(t["contact_sheet"]) if t["contact_sheet"] else None
    return d


def create_app(roots: list[Path], login: Login, tracker=None, mapping: dict | None = None) -> FastAPI:
    """The app for shots under ``roots`` (absolute folders), answering only with ``login``;
    with ``tracker`` (:class:`dailies.tracker.Tracker`) approved takes can be sent to it,
    its shots named through ``mapping`` (:func:`dailies.tracker.names`)."""
    roots = [Path(r) for r in roots]
    app = FastAPI(title="usd-tween dailies", openapi_url="/api/openapi.json", docs_url=None, redoc_url=None)
    templates = Jinja2Templates(directory=str(HERE / "templates"))

    @app.exception_handler(RequestValidationError)
    def invalid(request: Request, exc: RequestValidationError):
        # FastAPI's own answer echoes the input, and a NaN or Infinity in it (Python's json
        # reads them) cannot be written back as JSON: the reply was a 500.
        detail = [{"loc": list(e.get("loc", ())), "msg": e.get("msg", ""), "type": e.get("type", "")}
                  for e in exc.errors()]  # fmt: skip
        return JSONResponse({"detail": detail}, status_code=422)

    app.mount("/static", StaticFiles(directory=str(HERE / "static")), name="static")

    def _shot(key: str) -> dict:
        shot = find(roots, key)
        if shot is None:
            raise HTTPException(404, f"{key}: no such shot under the roots")
        return _with_urls(roots, detail(shot))

    @app.get("/", response_class=HTMLResponse, include_in_schema=False)
    def index(request: Request):
        return templates.TemplateResponse(
            request, "index.html", {"shots": listing(roots), "roots": roots, "csrf": login.csrf}
        )

    @app.get("/shot/{key:path}", response_class=HTMLResponse, include_in_schema=False)
    def shot_page(request: Request, key: str):
        return templates.TemplateResponse(
            request,
            "shot.html",
            {"shot": _shot(key), "csrf": login.csrf, "tracker": tracker and tracker.name},
        )

    @app.get("/media/{index}/{rel:path}", include_in_schema=False)
    def media_file(index: int, rel: str):
        path = media.resolve(roots, index, rel)
        if path is None:
            raise HTTPException(404, "no such media under the roots")
        # FileResponse answers Range requests (206) so players can seek.
        return FileResponse(path, media_type=media.TYPES[path.suffix.lower()])

    @app.get("/api/shots", summary="Shots with fills under the roots: pending first, newest first")
    def api_shots() -> list[dict]:
        return listing(roots)

    @app.post(
        "/api/shots/{key:path}/approve", summary="Approve a take of the shot's latest fill (tween approve)"
    )
    def api_approve(key: str, body: Approval = Body(...)) -> dict:
        try:
            return decide.approve(roots, key, body.take, body.note, body.version, body.by)
        except LookupError:
            raise HTTPException(404, f"{key}: no such shot under the roots") from None
        except decide.Refused as e:
            raise HTTPException(409, str(e)) from None

    @app.post("/api/shots/{key:path}/publish", summary="Publish the approved take (tween publish)")
    def api_publish(key: str, body: Publication = Body(...)) -> dict:
        try:
            return decide.publish(roots, key, body.version)
        except LookupError:
            raise HTTPException(404, f"{key}: no such shot under the roots") from None
        except decide.Refused as e:
            raise HTTPException(409, str(e)) from None

    @app.post("/api/shots/{key:path}/tracker", summary="Send the approved take's MP4 and note to the tracker")
    def api_tracker(key: str, body: Publication = Body(...)) -> dict:
        if tracker is None:
            raise HTTPException(409, "no tracker configured (tween dailies --tracker kitsu)")
        try:
            return decide.send(roots, key, body.version, tracker, mapping)
        except LookupError:
            raise HTTPException(404, f"{key}: no such shot under the roots") from None
        except decide.Refused as e:
            raise HTTPException(409, str(e)) from None

    @app.post("/api/shots/{key:path}/render", summary="Render the takes without review media on the farm")
    def api_render(key: str, body: Publication = Body(...)) -> dict:
        shot = find(roots, key)
        if shot is None:
            raise HTTPException(404, f"{key}: no such shot under the roots")
        d = detail(shot)
        if body.version is not None and body.version != d["version"]:
            raise HTTPException(
                409, f"{key}: v{body.version:03d} is no longer the latest (v{d['version']:03d} is)"
            )
        version = d["takes"][0]["version"]  # the fill version whose media the page shows
        try:
            return farm.render(roots, shot, version, [t["take"] for t in d["takes"] if t["mp4"] is None])
        except TweenError as e:
            raise HTTPException(409, str(e)) from None

    @app.get("/api/jobs", summary="The farm's fill jobs for shots under the roots: queued, running, failed")
    def api_jobs(shot: str | None = Query(None, description="Only this shot's (its key).")) -> dict:
        if shot is None:
            return farm.listing(roots)
        found = find(roots, shot)
        if found is None:
            raise HTTPException(404, f"{shot}: no such shot under the roots")
        return farm.listing(roots, found.folder, found.stem)

    @app.post("/api/jobs/{job_id}/cancel", summary="Cancel a fill job (tween cancel): nothing of it kept")
    def api_cancel(job_id: str) -> dict:
        try:
            return farm.cancel(roots, job_id)
        except LookupError:
            raise HTTPException(404, f"{job_id}: no such job for a shot under the roots") from None
        except TweenError as e:
            raise HTTPException(409, str(e)) from None

    @app.get("/api/shots/{key:path}", summary="One shot: takes and media, keys, fill sources, history")
    def api_shot(key: str) -> dict:
        return _shot(key)

    return LoginMiddleware(app, login)
