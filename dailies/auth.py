"""Login for the dailies server: a token made at start-up, given once in the URL (like
Jupyter's), then a cookie; changing requests also carry a CSRF token.

Every request needs the cookie, the token as ``?token=`` (answered by setting the cookie and
redirecting to the same URL without it, so it leaves the address bar and history), or an
``Authorization: Bearer`` header (scripts; no CSRF token needed: a browser never adds that
header by itself).
"""

from __future__ import annotations

import hashlib
import hmac
import json
import secrets
from http.cookies import SimpleCookie
from urllib.parse import parse_qsl, quote, urlencode

SAFE = ("GET", "HEAD", "OPTIONS")
CSRF_HEADER = b"x-csrf-token"
#: The largest request body read (a decision's JSON, its note at most 10,000 characters, is
#: far under it): a 100 MB body took the server 800 MB before it was refused.
MAX_BODY = 1 << 20
TOO_LARGE = f"request body over {MAX_BODY:,} bytes"


def _here(path: str) -> str:
    """The login redirect's target: the page asked for, percent-encoded, on this server. A
    path with a CR/LF broke the response (no answer), and ``//host/`` led to another site."""
    if not path.startswith("/") or path.startswith("//") or not path.isprintable():
        return "/"
    return quote(path, safe="/:@!$&'()*+,;=-._~")


def new_token() -> str:
    return secrets.token_urlsafe(32)


class Login:
    """The server's secrets: the login token, its cookie's name and the CSRF token."""

    def __init__(self, token: str, secure: bool = False):
        self.token, self.secure = token, secure
        digest = hashlib.sha256(token.encode()).hexdigest()
        # Cookies ignore ports: servers on one host each get their own cookie name.
        self.cookie = f"tween_dailies_{digest[:10]}"
        self.session = hmac.new(token.encode(), b"session", hashlib.sha256).hexdigest()
        self.csrf = hmac.new(token.encode(), b"csrf", hashlib.sha256).hexdigest()

    def same(self, given: str | None, expected: str) -> bool:
        return given is not None and hmac.compare_digest(given.encode(), expected.encode())


def _headers(scope) -> dict[bytes, bytes]:
    return {k.lower(): v for k, v in scope.get("headers", [])}


async def _send_text(send, status: int, text: str, headers=(), as_json=False) -> None:
    body = json.dumps({"detail": text}).encode() if as_json else text.encode()
    kind = b"application/json" if as_json else b"text/plain; charset=utf-8"
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", kind), (b"content-length", str(len(body)).encode()),
                            (b"cache-control", b"no-store"), *headers]})  # fmt: skip
    await send({"type": "http.response.body", "body": body})


class LoginMiddleware:
    """ASGI middleware: nothing passes without a login; changing requests need the CSRF token."""

    def __init__(self, app, login: Login):
        self.app, self.login = app, login

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        h, login = _headers(scope), self.login
        api = scope["path"].startswith("/api")
        length = h.get(b"content-length", b"0").decode("latin-1").strip()
        if not length.isdigit() or int(length) > MAX_BODY:
            return await _send_text(send, 413, f"{TOO_LARGE}, or its length unreadable", as_json=api)
        query = dict(parse_qsl(scope.get("query_string", b"").decode("latin-1")))
        bearer = h.get(b"authorization", b"").decode("latin-1")
        if bearer.lower().startswith("bearer ") and login.same(bearer[7:].strip(), login.token):
            return await self.app(scope, receive, send)
        if "token" in query and scope["method"] in SAFE:
            if not login.same(query["token"], login.token):
                return await _send_text(
                    send, 401, "wrong token: open the URL tween dailies printed", as_json=api
                )
            rest = urlencode(
                [(k, v) for k, v in parse_qsl(scope["query_string"].decode("latin-1")) if k != "token"]
            )
            where = _here(scope["path"]) + (f"?{rest}" if rest else "")
            # Lax, not Strict: the URL is often opened from another site (a chat, a mail), and
            # a Strict cookie set there is not sent on the redirect that follows; cross-site
            # changes are stopped by the CSRF token (and Lax sends no cookie on a foreign POST).
            flags = "; HttpOnly; SameSite=Lax; Path=/" + ("; Secure" if login.secure else "")
            cookie = f"{login.cookie}={login.session}{flags}".encode()
            return await _send_text(
                send, 303, "logged in", [(b"location", where.encode()), (b"set-cookie", cookie)]
            )
        jar = SimpleCookie()
        try:
            jar.load(h.get(b"cookie", b"").decode("latin-1"))
        except Exception:  # a malformed Cookie header is no login
            jar = SimpleCookie()
        morsel = jar.get(login.cookie)
        if not login.same(morsel.value if morsel else None, login.session):
            return await _send_text(
                send,
                401,
                "login needed: open the URL tween dailies printed (it carries the token)",
                as_json=api,
            )
        if scope["method"] not in SAFE and not login.same(
            h.get(CSRF_HEADER, b"").decode("latin-1"), login.csrf
        ):
            return await _send_text(send, 403, "missing or wrong CSRF token: reload the page", as_json=api)
        return await self.app(scope, _counted(receive), send)


def _counted(receive):
    """``receive``, refusing a body past MAX_BODY as it arrives: one sent in chunks has no
    Content-Length to refuse it by up front (a chunked 100 MB body was read whole). FastAPI
    answers the HTTPException raised while it reads the body with its 413."""
    from starlette.exceptions import HTTPException  # here: `tween --help` imports no web stack

    seen = 0

    async def counted():
        nonlocal seen
        message = await receive()
        seen += len(message.get("body", b""))
        if seen > MAX_BODY:
            raise HTTPException(413, TOO_LARGE)
        return message

    return counted
