"""The page in a real browser: Playwright driving Debian's chromium (no browser download)."""

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.usd.dailies import decision

CHROMIUM = "/usr/bin/chromium"
TOKEN = "b" * 40


def _chromium() -> str:
    """Debian's chromium, installed with apt when missing (as root); Playwright downloads nothing."""
    if not os.path.exists(CHROMIUM) and os.geteuid() == 0 and shutil.which("apt-get"):
        env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
        subprocess.run(["apt-get", "install", "-y", "-q", "--no-install-recommends", "chromium"], env=env,
                       capture_output=True, timeout=900)  # fmt: skip
    if not os.path.exists(CHROMIUM):
        pytest.skip(f"no {CHROMIUM}, and it could not be installed here (apt-get install chromium, as root)")
    return CHROMIUM


@pytest.fixture
def server(roots):
    p = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "dailies", str(roots[0]), "--port", "0",
                          "--token", TOKEN], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    url = p.stdout.readline().strip()
    assert url, p.stderr.read()
    yield url
    p.send_signal(signal.SIGINT)
    try:
        p.wait(10)
    except subprocess.TimeoutExpired:
        p.kill()


@pytest.fixture
def browser():
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as pw:
        b = pw.chromium.launch(
            executable_path=_chromium(), args=["--autoplay-policy=no-user-gesture-required"]
        )
        yield b
        b.close()


FRAME = "v => Math.floor(v.currentTime * 30 + 1e-3)"


def test_review_and_approve_in_the_browser(server, browser, roots, tmp_path):
    base = server.split("/?token=")[0]
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    page.goto(server)
    page.wait_for_url(base + "/")
    page.click("text=sh010")
    page.wait_for_selector("video[data-take='1']")
    videos = page.locator("video[data-take]")
    assert videos.count() == 2
    page.wait_for_function("Array.from(document.querySelectorAll('video[data-take]')).every(v => v.readyState === 4)",
                           timeout=20000)  # fmt: skip
    # Seeking any take's player, as its own controls do, brings the others to the same frame.
    for lead, frame in (("1", 17), ("0", 4), ("1", 29)):
        page.eval_on_selector(
            f"video[data-take='{lead}']", f"v => {{ v.currentTime = ({frame} + 0.5) / 30; }}"
        )
        page.wait_for_function(
            f"Array.from(document.querySelectorAll('video[data-take]')).every(v => !v.seeking && "
            f"Math.floor(v.currentTime * 30 + 1e-3) === {frame})", timeout=10000
        )  # fmt: skip
        assert page.inner_text("#frame").startswith(f"frame {1001 + frame}")
    # The keyboard: a frame forward, every player follows.
    page.keyboard.press("ArrowRight")
    page.wait_for_function(
        "Array.from(document.querySelectorAll('video[data-take]')).every(v => !v.seeking && "
        "Math.floor(v.currentTime * 30 + 1e-3) === 30)", timeout=10000
    )  # fmt: skip
    # Space plays every take together; space again pauses them all on one frame.
    page.eval_on_selector("video[data-take='0']", "v => { v.currentTime = 0.25 / 30; }")
    page.keyboard.press("Space")
    page.wait_for_function("Array.from(document.querySelectorAll('video[data-take]')).every(v => !v.paused && v.currentTime > 0.2)",
                           timeout=10000)  # fmt: skip
    page.keyboard.press("Space")
    page.wait_for_function(
        "(() => { const f = Array.from(document.querySelectorAll('video[data-take]')).map(v => v.paused && !v.seeking "
        "? Math.floor(v.currentTime * 30 + 1e-3) : -1); return f[0] >= 0 && f.every(x => x === f[0]); })()",
        timeout=10000,
    )  # fmt: skip
    page.wait_for_selector("#jobs .note:has-text('no farm configured')")  # the farm's jobs: none here
    if os.environ.get("TWEEN_DAILIES_SCREENSHOT"):  # the README's picture
        page.screenshot(path=os.environ["TWEEN_DAILIES_SCREENSHOT"], full_page=True)
    # Approve take 1 through the page, with a note.
    page.click("[data-action='approve'][data-take='1']")
    page.fill("#note", "take 1: cleaner arcs")
    page.click("[data-action='confirm']")
    page.wait_for_selector("#message.ok")
    assert "approved take 1" in page.inner_text("#message")
    d = decision(roots[0] / "seq01" / "sh010.tween.v002.usda")
    assert (d["status"], d["take"], d["note"]) == ("approved", 1, "take 1: cleaner arcs")
    page.wait_for_selector("#status:has-text('approved')", timeout=10000)  # the page reloads
    # A second approval from a page that still shows v001 is told, not written.
    stale = browser.new_page()
    stale.goto(server)
    stale.goto(base + "/shot/0/seq01/sh010")
    assert stale.locator("[data-action='approve']").count() == 0  # decided: no approve buttons

    # Without the token: nothing; outside the roots: nothing.
    other = browser.new_context()
    r = other.request.get(base + "/shot/0/seq01/sh010")
    assert r.status == 401 and "sh010" not in r.text()
    assert other.request.get(base + "/media/0/seq01/review/sh010_v001_take0.mp4").status == 401
    outside = tmp_path / "secret.mp4"
    outside.write_bytes(b"not yours")
    os.symlink(outside, roots[0] / "seq01" / "review" / "secret.mp4")
    for path in ("/media/0/seq01/review/secret.mp4", "/media/0/%2e%2e/%2e%2e/%2e%2e/etc/hostname",
                 "/media/0/seq01/sh010.usda"):  # fmt: skip
        r = page.request.get(base + path)
        assert r.status == 404 and b"not yours" not in r.body(), path
    other.close()


def test_a_concurrent_approval_is_told_on_the_page(server, browser, roots):
    base = server.split("/?token=")[0]
    a, b = browser.new_page(), browser.new_page()
    for p in (a, b):
        p.goto(server)
        p.goto(base + "/shot/0/seq01/sh010")
    for p, take in ((a, "0"), (b, "1")):
        p.click(f"[data-action='approve'][data-take='{take}']")
        p.fill("#note", f"from page {take}")
    a.click("[data-action='confirm']")
    a.wait_for_selector("#message.ok")
    b.click("[data-action='confirm']")
    b.wait_for_selector("#message.error")
    assert "already approved: take 0" in b.inner_text("#message")
    assert sorted(x.name for x in Path(roots[0] / "seq01").glob("sh010.tween.v*")) == [
        "sh010.tween.v001.usda", "sh010.tween.v002.usda"]  # fmt: skip
