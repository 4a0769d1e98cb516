"""Media are served with range requests, and only from under the roots."""

import os

import pytest

MP4 = "/media/0/seq01/review/sh010_v001_take0.mp4"


def test_a_range_request_gets_those_bytes(client, roots):
    data = (roots[0] / "seq01/review/sh010_v001_take0.mp4").read_bytes()
    whole = client.get(MP4)
    assert whole.status_code == 200 and whole.content == data
    assert whole.headers["accept-ranges"] == "bytes" and whole.headers["content-type"] == "video/mp4"
    r = client.get(MP4, headers={"Range": "bytes=100-1099"})
    assert r.status_code == 206
    assert r.headers["content-range"] == f"bytes 100-1099/{len(data)}"
    assert r.content == data[100:1100]
    tail = client.get(MP4, headers={"Range": "bytes=-500"})
    assert tail.status_code == 206 and tail.content == data[-500:]
    assert client.get(MP4, headers={"Range": f"bytes={len(data) + 10}-"}).status_code == 416


@pytest.mark.parametrize(
    "path",
    ["/media/0/../../../../etc/passwd", "/media/0/%2e%2e/%2e%2e/etc/hostname", "/media/0//etc/hostname",
     "/media/1/seq01/review/sh010_v001_take0.mp4", "/media/0/seq01/sh010.usda", "/media/0/seq01/nothing.mp4"],
)  # fmt: skip
def test_nothing_outside_the_roots_or_not_media(client, path):
    r = client.get(path)
    assert r.status_code == 404
    assert b"root:" not in r.content and b"#usda" not in r.content


def test_symlinks_are_followed_and_checked(client, roots, tmp_path):
    outside = tmp_path / "outside.mp4"
    outside.write_bytes(b"secret movie")
    review = roots[0] / "seq01" / "review"
    os.symlink(outside, review / "leak.mp4")
    os.symlink(tmp_path, review / "up")
    assert client.get("/media/0/seq01/review/leak.mp4").status_code == 404
    assert client.get("/media/0/seq01/review/up/outside.mp4").status_code == 404
    os.symlink(review / "sh010_v001_take1.mp4", review / "inside.mp4")  # a link within the roots is fine
    r = client.get("/media/0/seq01/review/inside.mp4")
    assert r.status_code == 200 and r.content == (review / "sh010_v001_take1.mp4").read_bytes()


def test_resolve_refuses_every_way_out(roots):
    from dailies.media import resolve

    root = roots[0]
    assert (
        resolve(roots, 0, "seq01/review/sh010_v001_take0.mp4") == root / "seq01/review/sh010_v001_take0.mp4"
    )
    for rel in ("../x.mp4", "seq01/../../x.mp4", "/etc/x.mp4", "seq01/review/../../../x.png", "seq01\0.mp4"):
        assert resolve(roots, 0, rel) is None, rel
    assert resolve(roots, 1, "seq01/review/sh010_v001_take0.mp4") is None
    assert resolve(roots, -1, "seq01/review/sh010_v001_take0.mp4") is None


def test_a_media_name_that_leads_to_a_layer_or_a_shot_is_no_media(client, roots):
    """A link named .mp4 to a fill layer (or .png to the shot) under the roots was a 500: the
    name was media, what it led to had no media type. Layers and shots are never served."""
    review = roots[0] / "seq01" / "review"
    os.symlink(roots[0] / "seq01" / "sh010.tween.v001.usda", review / "layer.mp4")
    os.symlink(roots[0] / "seq01" / "sh010.usda", review / "shot.png")
    for name in ("layer.mp4", "shot.png"):
        r = client.get(f"/media/0/seq01/review/{name}")
        assert r.status_code == 404 and b"#usda" not in r.content


def test_a_pipe_named_like_a_fill_layer_is_no_shot(client, roots):
    """A FIFO named like a fill layer under a root blocked every request that listed or read
    it (each held a server thread for good), and Ctrl-C no longer stopped the server."""
    os.mkfifo(roots[0] / "seq01" / "sh090.tween.v001.usda")
    os.mkfifo(roots[0] / "seq01" / "sh010.tween.v009.usda")  # beside a real shot's layers
    shots = client.get("/api/shots")
    assert shots.status_code == 200
    keys = {s["key"]: s for s in shots.json()}
    assert "0/seq01/sh090" not in keys and keys["0/seq01/sh010"]["version"] != 9
    assert client.get("/api/shots/0/seq01/sh090").status_code == 404
    assert client.get("/api/shots/0/seq01/sh010").status_code == 200
