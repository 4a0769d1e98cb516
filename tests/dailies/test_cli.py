"""`tween dailies`: the URL first on stdout, bad input one line (exit 2), loopback by default."""

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request

import pytest

TWEEN = [sys.executable, "-m", "pipeline.cli", "dailies"]


def _run(*args, timeout=60):
    return subprocess.run([*TWEEN, *map(str, args)], capture_output=True, text=True, timeout=timeout)


def _one_error(r, *words):
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("tween: error: "), r.stderr
    assert r.stdout == ""
    for w in words:
        assert w in lines[0], lines[0]


def test_bad_input_is_one_line(tmp_path):
    _one_error(_run(tmp_path / "nope"), "nope: no such folder")
    (tmp_path / "f.usda").write_text("#usda 1.0\n")
    _one_error(_run(tmp_path / "f.usda"), "not a folder")
    _one_error(_run(tmp_path, "--certfile", tmp_path / "f.usda"), "--certfile and --keyfile")
    _one_error(
        _run(tmp_path, "--certfile", tmp_path / "f.usda", "--keyfile", tmp_path / "f.usda"), "cannot load"
    )
    _one_error(_run(tmp_path, "--port", "70000"), "--port 70000")
    _one_error(_run(tmp_path, "--token", "short"), "--token")
    for token in (" " * 20, "é" * 20, "a b" * 8):  # taken, and printed unencoded in the URL
        _one_error(_run(tmp_path, "--token", token), "--token (or TWEEN_DAILIES_TOKEN): letters, digits")
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        _one_error(_run(tmp_path, "--port", busy.getsockname()[1]), "cannot listen there")


@pytest.fixture
def serve(roots):
    procs = []

    def start(*args):
        p = subprocess.Popen([*TWEEN, str(roots[0]), "--port", "0", *args], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)  # fmt: skip
        procs.append(p)
        url = p.stdout.readline().strip()
        assert url, p.stderr.read()
        return p, url

    yield start
    for p in procs:
        p.send_signal(signal.SIGINT)
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            p.kill()


def _get(url, **headers):
    req = urllib.request.Request(url, headers=headers)
    for _ in range(100):  # the server answers once uvicorn has started
        try:
            return urllib.request.urlopen(req, timeout=10)
        except urllib.error.HTTPError as e:
            return e
        except urllib.error.URLError:
            time.sleep(0.1)
    raise AssertionError(f"{url}: no answer")


def test_serves_on_loopback_with_the_token_in_the_first_line(serve):
    p, url = serve()
    assert url.startswith("http://127.0.0.1:") and "/?token=" in url
    base, token = url.split("/?token=")
    assert len(token) >= 40
    assert _get(base + "/api/shots").status == 401
    r = _get(base + "/api/shots", Authorization=f"Bearer {token}")
    assert r.status == 200 and b'"0/seq01/sh010"' in r.read()
    import http.cookiejar

    browser = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(http.cookiejar.CookieJar()))
    page = browser.open(url, timeout=10)  # the token, then the cookie through the redirect
    assert page.status == 200 and page.url == base + "/" and b"sh010" in page.read()
    assert b"sh010" in browser.open(base + "/shot/0/seq01/sh010", timeout=10).read()
    assert _get(base + "/media/0/seq01/review/sh010_v001_take0.mp4", Authorization=f"Bearer {token}",
                Range="bytes=0-99").status == 206  # fmt: skip


def test_another_host_without_tls_warns(serve):
    p, url = serve("--host", "0.0.0.0")
    assert not url.startswith("http://127.0.0.1")
    line = p.stderr.readline()
    assert "warning: listening on 0.0.0.0 without TLS" in line


def test_tls(serve, tmp_path):
    cert, key = tmp_path / "c.pem", tmp_path / "k.pem"
    made = subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", key, "-out", cert,
                           "-days", "1", "-subj", "/CN=127.0.0.1"], capture_output=True)  # fmt: skip
    if made.returncode:
        pytest.skip("openssl cannot make a test certificate here")
    import ssl

    p, url = serve("--certfile", str(cert), "--keyfile", str(key))
    assert url.startswith("https://127.0.0.1:")
    base, token = url.split("/?token=")
    ctx = ssl.create_default_context(cafile=str(cert))
    ctx.check_hostname = False
    req = urllib.request.Request(base + "/api/shots", headers={"Authorization": f"Bearer {token}"})
    for _ in range(100):
        try:
            r = urllib.request.urlopen(req, timeout=10, context=ctx)
            break
        except urllib.error.URLError:
            time.sleep(0.1)
    assert r.status == 200


def test_help_stays_light():
    """`tween --help` does not import the web stack (the command imports it when run)."""
    code = "import sys, pipeline.cli; print(sorted(m for m in sys.modules if m.split('.')[0] in ('fastapi', 'uvicorn', 'starlette')))"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                       env={**os.environ})  # fmt: skip
    assert r.stdout.strip() == "[]", r.stdout
