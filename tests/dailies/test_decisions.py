"""Decisions from the page are `tween approve` / `tween publish`'s: the same layers, the same
refusals (already approved, stale version, a concurrent approval), shown as one message."""

import json
import subprocess
import sys
import threading

from dailies_fixtures import filled_shot

from pipeline.usd.dailies import decision

KEY = "0/seq01/sh010"
APPROVE, PUBLISH = f"/api/shots/{KEY}/approve", f"/api/shots/{KEY}/publish"


def _post(client, url, body):
    return client.post(url, json=body, headers={"X-CSRF-Token": client.login.csrf})


def test_approve_from_the_page_records_the_take_and_the_note(client, roots):
    folder = roots[0] / "seq01"
    r = _post(client, APPROVE, {"take": 1, "note": "arc on the hand, good", "version": 1, "by": " Ana Ruiz "})
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["version"] == 2 and out["take"] == 1 and out["of_version"] == 1
    d = decision(folder / "sh010.tween.v002.usda")
    assert (d["status"], d["take"], d["note"], d["by"]) == (
        "approved",
        1,
        "arc on the hand, good",
        "Ana Ruiz",
    )
    assert decision(folder / "sh010.tween.v001.usda")["layer"].endswith("v002.usda")  # v001 is unchanged
    # The CLI sees the page's decision as its own: approving again is refused the same way.
    cli = subprocess.run([sys.executable, "-m", "pipeline.cli", "approve", str(folder / "sh010.usda"), "--take", "0"],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert cli.returncode == 2 and "already approved (take 1 by Ana Ruiz" in cli.stderr
    detail = client.get(f"/api/shots/{KEY}").json()
    assert detail["status"] == "approved" and detail["decision"]["take"] == 1
    assert [h["version"] for h in detail["history"]] == [2, 1]
    assert detail["history"][0]["decision"]["note"] == "arc on the hand, good"
    # The approval shows the renders of the fill it approved (its takes are the same samples).
    assert [t["mp4_url"] for t in detail["takes"]][1].endswith("sh010_v001_take1.mp4")


def test_refusals_are_one_message(client, roots):
    folder = roots[0] / "seq01"
    bad_take = _post(client, APPROVE, {"take": 7, "version": 1})  # approve's own check
    assert bad_take.status_code == 409 and "take 7 is not one of the layer's takes (0, 1)" in bad_take.text
    negative = _post(client, APPROVE, {"take": -1})  # refused by the API's schema
    assert negative.status_code == 422
    for odd in ({"take": True}, {"take": "1"}, {"take": 1.0}, {"take": 0, "version": True}):  # not read as 1
        assert _post(client, APPROVE, odd).status_code == 422, odd
    assert _post(client, PUBLISH, {"version": "1"}).status_code == 422
    # NaN and Infinity (Python's json reads them): the schema's answer echoed them and could
    # not be written as JSON (a 500).
    bodies = {APPROVE: (b'{"take": NaN, "version": 1}', b'{"take": Infinity}', b'{"take": 1e400}'),
              PUBLISH: (b'{"version": NaN}', b'{"version": -Infinity}', b'{"version": 1e999}')}  # fmt: skip
    for url, raws in bodies.items():
        for raw in raws:
            r = client.post(url, content=raw, headers={"X-CSRF-Token": client.login.csrf,
                                                       "Content-Type": "application/json"})  # fmt: skip
            assert r.status_code == 422 and r.json()["detail"], (url, raw, r.text)
    # Keys and media names too long for a path (ENAMETOOLONG) name nothing: 404, not a 500.
    for url in (f"/api/shots/0/{'b/' * 2100}x", f"/media/0/{'a' * 5000}.mp4", f"/media/0/{'a/' * 3000}x.mp4"):
        assert client.get(url).status_code == 404, url
    assert _post(client, f"/api/shots/0/{'b/' * 2100}x/approve", {"take": 0}).status_code == 404
    # The approval's own rules on the name and the note are the schema's: invalid, not a conflict.
    for body in ({"by": "\t"}, {"by": "ana\nbo"}, {"by": "a\0b"}, {"by": "x" * 201}, {"note": "ok\0"}):
        r = _post(client, APPROVE, {"take": 0, "version": 1, **body})
        assert r.status_code == 422, (body, r.text)
        (err,) = r.json()["detail"]
        assert err["loc"][-1] in body and any(w in err["msg"] for w in ("name", "NUL", "200 characters")), err
    assert _post(client, APPROVE, {"take": 0, "version": 1}).status_code == 200
    again = _post(client, APPROVE, {"take": 1, "version": 2})  # the layer's own refusal
    assert again.status_code == 409 and "already approved (take 0 by" in again.json()["detail"]
    stale = _post(client, APPROVE, {"take": 1, "version": 1})  # the page showed v001
    assert stale.status_code == 409 and "already approved: take 0" in stale.json()["detail"]
    assert sorted(p.name for p in folder.glob("sh010.tween.v*")) == [
        "sh010.tween.v001.usda",
        "sh010.tween.v002.usda",
    ]


def test_a_newer_fill_makes_the_page_stale(client, roots):
    from pipeline.fill.api import FillOptions, fill_shot

    fill_shot(str(roots[0] / "seq01" / "sh010.usda"), FillOptions(model="interp", takes=2))  # v002
    r = _post(client, APPROVE, {"take": 0, "version": 1})
    assert r.status_code == 409 and "stale: the latest is v002, this page showed v001" in r.json()["detail"]
    assert not (roots[0] / "seq01" / "sh010.tween.v003.usda").exists()


def test_two_browsers_approving_at_once_one_wins(roots):
    from dailies_fixtures import client_for

    a, b = client_for(roots), client_for(roots)
    results = {}
    go = threading.Barrier(2)

    def approve(name, c, take):
        go.wait()
        results[name] = _post(c, APPROVE, {"take": take, "note": name, "version": 1})

    threads = [threading.Thread(target=approve, args=(n, c, t)) for n, c, t in (("a", a, 0), ("b", b, 1))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    codes = sorted(r.status_code for r in results.values())
    assert codes == [200, 409], {k: r.text for k, r in results.items()}
    winner = next(k for k, r in results.items() if r.status_code == 200)
    loser = next(k for k, r in results.items() if r.status_code == 409)
    assert "already approved" in results[loser].json()["detail"]
    layers = sorted(p.name for p in (roots[0] / "seq01").glob("sh010.tween.v*"))
    assert layers == ["sh010.tween.v001.usda", "sh010.tween.v002.usda"]  # one decision, not two
    assert decision(roots[0] / "seq01" / "sh010.tween.v002.usda")["note"] == winner


def test_publish_from_the_page_is_tween_publish(client, roots, tmp_path):
    folder = roots[0] / "seq01"
    early = _post(client, PUBLISH, {"version": 1})
    assert early.status_code == 409 and "nothing approved" in early.json()["detail"]
    assert _post(client, APPROVE, {"take": 1, "note": "ok", "version": 1}).status_code == 200
    r = _post(client, PUBLISH, {"version": 2})
    assert r.status_code == 200, r.text
    page = (folder / "sh010.publish.v002.usda").read_text()
    # The CLI's publish of the same decision writes the same animation, sample for sample.
    cli = subprocess.run([sys.executable, "-m", "pipeline.cli", "publish", str(folder / "sh010.usda"),
                          "--out", str(tmp_path / "cli.usda")], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert cli.returncode == 0, cli.stderr
    body = lambda text: text[text.index('over "World"') :]  # noqa: E731  (metadata holds the time)
    assert body(page) == body((tmp_path / "cli.usda").read_text())
    again = _post(client, PUBLISH, {"version": 2})
    assert again.status_code == 409 and "never overwritten" in again.json()["detail"]
    assert json.loads(client.get("/api/shots").text)[0]["published"] is True


def test_the_list_puts_pending_shots_first_newest_first(client, roots):
    filled_shot(roots[0] / "seq02", "sh020", takes=1, render=False)
    filled_shot(roots[0] / "seq02", "sh030", takes=1, render=False)
    keys = [s["key"] for s in client.get("/api/shots").json()]
    assert keys == ["0/seq02/sh030", "0/seq02/sh020", "0/seq01/sh010"]
    assert _post(client, "/api/shots/0/seq02/sh030/approve", {"take": 0, "version": 1}).status_code == 200
    rows = client.get("/api/shots").json()
    assert [(s["key"], s["status"]) for s in rows] == [
        ("0/seq02/sh020", "pending"), ("0/seq01/sh010", "pending"), ("0/seq02/sh030", "approved")
    ]  # fmt: skip
    page = client.get("/").text
    assert page.index("sh020") < page.index("sh010") < page.index("sh030")


def test_the_walk_is_reused_but_a_decision_shows_at_once(client, roots, monkeypatch):
    from dailies import shots

    monkeypatch.setattr(shots, "SCAN_AGE", 60.0)
    assert [s["key"] for s in client.get("/api/shots").json()] == [KEY]
    filled_shot(roots[0] / "seq05", "sh100", takes=1, render=False)
    assert [s["key"] for s in client.get("/api/shots").json()] == [KEY]  # within SCAN_AGE: the last walk
    assert _post(client, APPROVE, {"take": 0, "version": 1}).status_code == 200
    rows = {s["key"]: s["status"] for s in client.get("/api/shots").json()}
    assert rows == {KEY: "approved", "0/seq05/sh100": "pending"}  # a decision: walked again


def test_tween_approve_names_the_reviewer(tmp_path):
    made = filled_shot(tmp_path / "seq09", "sh900", takes=2, render=False, frames=13)
    run = [sys.executable, "-m", "pipeline.cli", "approve", str(made["shot"]), "--take", "1"]
    bad = subprocess.run([*run, "--by", "  "], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "--by" in bad.stderr, bad.stderr
    assert not list((tmp_path / "seq09").glob("sh900.tween.v002.*"))  # refused before anything is written
    ok = subprocess.run(
        [*run, "--by", "Ana Ruiz", "--note", "good"], capture_output=True, text=True, timeout=120
    )
    assert ok.returncode == 0, ok.stderr
    assert json.loads(ok.stdout)["by"] == "Ana Ruiz"
    assert decision(tmp_path / "seq09" / "sh900.tween.v002.usda")["by"] == "Ana Ruiz"


def test_a_fill_copied_from_another_shot_is_not_decided_for_it(client, roots):
    """Fill layers copied beside another shot name the shot they were made from: approving
    them under the copy's key approved that other shot's fill (a new version of it)."""
    import shutil

    folder = roots[0] / "seq01"
    shutil.copy(folder / "sh010.usda", folder / "sh099.usda")
    shutil.copy(folder / "sh010.tween.v001.usda", folder / "sh099.tween.v001.usda")
    before = sorted(p.name for p in folder.iterdir())
    r = _post(client, "/api/shots/0/seq01/sh099/approve", {"take": 1, "version": 1})
    assert r.status_code == 409, r.text
    assert "sh099: sh099.tween.v001.usda is a fill of sh010.usda, not of a shot sh099" in r.json()["detail"]
    assert sorted(p.name for p in folder.iterdir()) == before
