"""Nothing is readable or changeable without the login; changing requests need the CSRF token."""

import pytest
from dailies_fixtures import TOKEN, client_for

PATHS = ["/", "/shot/0/seq01/sh010", "/media/0/seq01/review/sh010_v001_take0.mp4", "/api/shots",
         "/api/shots/0/seq01/sh010", "/api/openapi.json", "/static/dailies.js", "/docs"]  # fmt: skip


@pytest.mark.parametrize("path", PATHS)
def test_nothing_without_the_token(roots, path):
    c = client_for(roots, login=False)
    r = c.get(path)
    assert r.status_code == 401
    assert b"sh010" not in r.content and b"ftyp" not in r.content
    assert c.get(path, headers={"Authorization": "Bearer wrong"}).status_code == 401
    c.cookies.set(c.login.cookie, "forged")
    assert c.get(path).status_code == 401


def test_a_wrong_token_is_refused(roots):
    c = client_for(roots, login=False)
    r = c.get("/?token=" + "x" * 40, follow_redirects=False)
    assert r.status_code == 401 and "set-cookie" not in r.headers


def test_the_token_sets_a_cookie_and_leaves_the_url(roots):
    c = client_for(roots, login=False)
    r = c.get(f"/shot/0/seq01/sh010?token={TOKEN}", follow_redirects=False)
    assert r.status_code == 303
    assert r.headers["location"] == "/shot/0/seq01/sh010"  # the token leaves the address bar
    cookie = r.headers["set-cookie"]
    assert "HttpOnly" in cookie and "SameSite=Lax" in cookie and TOKEN not in cookie
    assert c.get("/shot/0/seq01/sh010").status_code == 200  # the cookie from now on


def test_changing_requests_need_the_csrf_token(client, roots):
    body = {"take": 1, "note": "no csrf"}
    r = client.post("/api/shots/0/seq01/sh010/approve", json=body)
    assert r.status_code == 403 and "CSRF" in r.json()["detail"]
    r = client.post("/api/shots/0/seq01/sh010/approve", json=body, headers={"X-CSRF-Token": "0" * 64})
    assert r.status_code == 403
    assert not list((roots[0] / "seq01").glob("sh010.tween.v002.*"))  # nothing was decided
    # The page carries the token for its scripts.
    assert client.login.csrf in client.get("/shot/0/seq01/sh010").text


def test_a_script_logs_in_with_a_bearer_header(roots):
    c = client_for(roots, login=False)
    auth = {"Authorization": f"Bearer {TOKEN}"}
    assert c.get("/api/shots", headers=auth).json()[0]["key"] == "0/seq01/sh010"
    r = c.post("/api/shots/0/seq01/sh010/approve", json={"take": 0}, headers=auth)
    assert r.status_code == 200, r.text  # no cookie, so no CSRF token needed


def test_two_servers_on_one_host_keep_their_own_cookie(roots):
    a, b = client_for(roots, "a" * 40, login=False), client_for(roots, "b" * 40, login=False)
    assert a.login.cookie != b.login.cookie


@pytest.mark.parametrize(
    "path, where",
    [
        ("/%0d%0aX-Injected:%20y", "/"),
        ("//evil.example/", "/"),
        ("/shot/0/seq01/sh 010", "/shot/0/seq01/sh%20010"),
    ],
)
def test_the_login_redirect_stays_on_this_server_and_answers(roots, path, where):
    """A CR/LF in the path left the login without an answer (the server could not write that
    Location header), and ``//evil.example/`` sent the browser to another site."""
    c = client_for(roots, login=False)
    r = c.get(f"{path}?token={TOKEN}", follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == where
    assert "x-injected" not in r.headers


def test_a_request_body_over_the_limit_is_refused_unread(client):
    """A 100 MB body was read whole before it was refused (the server grew by 800 MB)."""
    from dailies.auth import MAX_BODY

    headers = {"X-CSRF-Token": client.login.csrf, "Content-Type": "application/json"}
    r = client.post("/api/shots/0/seq01/sh010/approve", content=b"[" + b"0," * (MAX_BODY // 2) + b"0]",
                    headers=headers)  # fmt: skip
    assert r.status_code == 413 and "request body over" in r.json()["detail"]
    assert client.get("/api/shots").status_code == 200  # and the server answers on


def test_a_body_sent_in_chunks_is_refused_past_the_limit(client):
    """A chunked body carries no Content-Length to refuse it by: it was read whole (100 MB)."""
    headers = {"X-CSRF-Token": client.login.csrf, "Content-Type": "application/json"}
    big = iter([b" " * (1 << 16)] * 64)  # 4 MiB, 64 KiB a chunk
    r = client.post("/api/shots/0/seq01/sh010/approve", content=big, headers=headers)
    assert "content-length" not in {k.lower() for k in r.request.headers}  # it was chunked
    assert r.status_code == 413 and "request body over" in r.json()["detail"]
    assert client.get("/api/shots").status_code == 200
    small = client.post("/api/shots/0/seq01/sh010/approve", content=iter([b"{}"]), headers=headers)
    assert small.status_code == 422  # a small chunked body is read (and this one lacks the take)
