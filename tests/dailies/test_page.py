"""The shot page: every take's player, the approve buttons, the keys and what filled the frames."""

import json
import re

from dailies_fixtures import filled_shot


def _data(html: str) -> dict:
    return json.loads(
        re.search(r'<script id="shot-data" type="application/json">(.*?)</script>', html, re.S)[1]
    )


def test_every_take_has_a_player_and_an_approve_button(client):
    html = client.get("/shot/0/seq01/sh010").text
    videos = re.findall(r'<video data-take="(\d)" src="([^"]+)"', html)
    assert videos == [("0", "/media/0/seq01/review/sh010_v001_take0.mp4"),
                      ("1", "/media/0/seq01/review/sh010_v001_take1.mp4")]  # fmt: skip
    for _, url in videos:
        assert client.get(url, headers={"Range": "bytes=0-11"}).content[4:8] == b"ftyp"
    assert re.findall(r'data-action="approve" data-take="(\d)"', html) == ["0", "1"]
    assert 'data-action="confirm"' in html
    data = _data(html)
    assert data["keys"] == [1001, 1011, 1021, 1031] and data["frame_range"] == [1001, 1031]
    assert data["fps"] == 30 and data["version"] == 1
    assert "interpolation on every in-between" in html  # no trust decision: the model filled all
    assert "/static/dailies.js" in html
    assert "video[data-take]" in client.get("/static/dailies.js").text  # the script is served


def test_fill_sources_per_character_are_shown():
    from pxr import Sdf

    from dailies.detail import _character

    class Attr:
        def __init__(self, v):
            self.default = v

    class Spec:  # an Sdf prim spec's shape, as _character reads it
        path = Sdf.Path("/World/Char/Skel/Anim_tween")
        name = "Anim_tween"
        attributes = {"tween:model": Attr("g2"), "tween:keyTimes": Attr([1001.0, 1011.0, 1021.0]),
                      "tween:trust": Attr("blend"), "tween:trustWeight": Attr(0.5),
                      "tween:trustGaps": Attr([(1001.0, 1011.0), (1011.0, 1021.0)]),
                      "tween:trustGapWeights": Attr([1.0, 0.4])}  # fmt: skip

    c = _character(Spec())
    assert c["path"] == "/World/Char/Skel/Anim" and c["model"] == "g2"
    assert c["sources"] == [[1001.0, 1011.0, "model"], [1011.0, 1021.0, "model 40%"]]


def test_a_take_without_renders_says_so(client, roots):
    filled_shot(roots[0] / "seq02", "sh020", takes=2, render=False)
    html = client.get("/shot/0/seq02/sh020").text
    assert "<video" not in html
    assert html.count("not rendered") == 2 and "--take 1" in html
    assert re.findall(r'data-action="approve" data-take="(\d)"', html) == ["0", "1"]
    d = client.get("/api/shots/0/seq02/sh020").json()
    assert [t["mp4_url"] for t in d["takes"]] == [None, None]
    assert d["frame_range"] == [1001, 1031] and d["fps"] == 30  # from the shot itself


def test_an_unknown_shot_is_404(client):
    for key in ("0/seq01/sh999", "3/seq01/sh010", "0/../sh010", "x/sh010"):
        assert client.get(f"/api/shots/{key}").status_code == 404, key


def test_the_api_has_its_openapi_schema(client):
    schema = client.get("/api/openapi.json").json()
    paths = schema["paths"]
    assert {"/api/shots", "/api/shots/{key}", "/api/shots/{key}/approve", "/api/shots/{key}/publish"} <= set(
        paths
    )
    assert "take" in json.dumps(schema["components"]["schemas"]["Approval"])
    assert not any(p.startswith(("/media", "/shot")) for p in paths)


def test_a_linked_folder_out_of_the_roots_is_no_shot(client, roots, tmp_path):
    import os

    outside = tmp_path / "elsewhere"
    filled_shot(outside, "sh050", takes=1, render=False)
    os.symlink(outside, roots[0] / "linked")
    assert "sh050" not in client.get("/").text  # the scan does not follow it
    assert client.get("/api/shots/0/linked/sh050").status_code == 404  # nor does a key
    r = client.post("/api/shots/0/linked/sh050/approve", json={"take": 0},
                    headers={"X-CSRF-Token": client.login.csrf})  # fmt: skip
    assert r.status_code == 404 and not list(outside.glob("sh050.tween.v002*"))


def test_a_note_is_text_never_markup(client):
    note = '<script>alert("x")</script> & </script><b>'
    r = client.post("/api/shots/0/seq01/sh010/approve", json={"take": 0, "note": note, "version": 1},
                    headers={"X-CSRF-Token": client.login.csrf})  # fmt: skip
    assert r.status_code == 200
    for page in (client.get("/").text, client.get("/shot/0/seq01/sh010").text):
        assert "<script>alert" not in page and "</script><b>" not in page
        assert "&lt;script&gt;alert" in page


def test_odd_folder_names_make_working_links(client, roots):
    filled_shot(roots[0] / "seq 04#b", "sh090", takes=2)
    html = client.get("/").text
    link = re.search(r'href="(/shot/0/seq[^"]*sh090)"', html)[1]
    assert link == "/shot/0/seq%2004%23b/sh090"
    page = client.get(link).text
    for url in re.findall(r'<video data-take="\d" src="([^"]+)"', page):
        assert client.get(url, headers={"Range": "bytes=0-11"}).status_code == 206, url
    r = client.post("/api/shots/0/seq%2004%23b/sh090/approve", json={"take": 1, "version": 1},
                    headers={"X-CSRF-Token": client.login.csrf})  # fmt: skip
    assert r.status_code == 200 and r.json()["layer"].endswith("seq 04#b/sh090.tween.v002.usda")
