"""The approved take reaches Kitsu: a real zou server (PostgreSQL, Redis) started here."""

import json
import subprocess
import sys

import pytest
from dailies_fixtures import client_for, filled_shot
from kitsu_server import ADMIN, PASSWORD, KitsuServer

from dailies.tracker import TrackerError, names
from dailies.trackers import make

PROJECT = "tween-dailies"


@pytest.fixture(scope="module")
def kitsu():
    server = KitsuServer()
    try:
        yield server.start()
    finally:
        server.stop()


@pytest.fixture(scope="module")
def task(kitsu):
    """Project tween-dailies, sequence sq01, shot sh010 with an Animation task."""
    import gazu

    c = gazu.client.create_client(kitsu.url)
    gazu.log_in(ADMIN, PASSWORD, client=c)
    project = gazu.project.new_project(PROJECT, client=c)
    anim = gazu.task.get_task_type_by_name("Animation", client=c)
    gazu.project.add_task_type(project, anim, 1, client=c)
    seq = gazu.shot.new_sequence(project, "sq01", client=c)
    gazu.shot.new_shot(project, seq, "sh020", client=c)  # a shot without its animation task
    shot = gazu.shot.new_shot(project, seq, "sh010", client=c)
    return {"client": c, "task": gazu.task.new_task(shot, anim, client=c)}


def _settings(kitsu, **kw):
    return {"url": kitsu.url, "user": ADMIN, "password": PASSWORD, "project": PROJECT, **kw}


def _approved(root, name, take=1, note="arcs fixed, approved"):
    filled_shot(root / "sq01", name)
    c = client_for([root])
    r = c.post(f"/api/shots/0/sq01/{name}/approve", json={"take": take, "note": note, "version": 1},
               headers={"X-CSRF-Token": c.login.csrf})  # fmt: skip
    assert r.status_code == 200, r.text


def test_the_approved_take_becomes_the_tasks_preview(kitsu, task, tmp_path):
    import gazu

    root = tmp_path / "shots"
    _approved(root, "sq01_sh010")
    c = client_for([root], tracker=make("kitsu", _settings(kitsu)))
    page = c.get("/shot/0/sq01/sq01_sh010").text
    assert 'data-action="tracker"' in page and "Send to Kitsu" in page
    r = c.post(
        "/api/shots/0/sq01/sq01_sh010/tracker", json={"version": 2}, headers={"X-CSRF-Token": c.login.csrf}
    )
    assert r.status_code == 200, r.text
    out = r.json()
    assert (out["tracker"], out["sequence"], out["shot"], out["take"]) == ("kitsu", "sq01", "sh010", 1)
    assert out["preview_status"] == "ready"
    k = task["client"]
    previews = gazu.files.get_all_preview_files_for_task(task["task"], client=k)
    assert [p["id"] for p in previews] == [out["preview"]]
    movie = tmp_path / "back.mp4"
    gazu.files.download_preview_movie(previews[0], str(movie), client=k)
    sent = root / "sq01" / "review" / "sq01_sh010_v001_take1.mp4"
    assert movie.read_bytes() == sent.read_bytes()  # take 1's own turntable, as rendered
    comment = gazu.task.get_last_comment_for_task(task["task"], client=k)
    assert (
        comment["text"].startswith("arcs fixed, approved")
        and "take 1 of sq01_sh010.tween.v002.usda" in comment["text"]
    )
    status = gazu.task.get_task_status_by_short_name("wfa", client=k)
    assert gazu.task.get_task(task["task"]["id"], client=k)["task_status_id"] == status["id"]
    again = c.post("/api/shots/0/sq01/sq01_sh010/tracker", json={"version": 2},
                   headers={"X-CSRF-Token": c.login.csrf})  # fmt: skip
    assert again.status_code == 409 and "already sent to kitsu" in again.json()["detail"]
    assert len(gazu.files.get_all_preview_files_for_task(task["task"], client=k)) == 1


def test_a_missing_shot_or_task_is_one_clear_line(kitsu, task, tmp_path):
    root = tmp_path / "shots"
    _approved(root, "sq01_sh999")
    _approved(root, "sq01_sh020")
    _approved(root, "sq07_sh010")
    for name, line, settings in (
        ("sq01_sh999", "sequence 'sq01' of 'tween-dailies' has no shot 'sh999'", {}),
        ("sq01_sh020", "shot sq01/sh020 has no 'Animation' task", {}),
        ("sq07_sh010", "project 'tween-dailies' has no sequence 'sq07'", {}),
        ("sq01_sh010", "no project 'nope'", {"project": "nope"}),
        ("sq01_sh999", "login refused for admin@example.com", {"password": "wrong-password"}),
    ):
        if name == "sq01_sh010":
            _approved(root, name)
        c = client_for([root], tracker=make("kitsu", _settings(kitsu, **settings)))
        r = c.post(f"/api/shots/0/sq01/{name}/tracker", json={}, headers={"X-CSRF-Token": c.login.csrf})
        assert r.status_code == 409 and line in r.json()["detail"], (name, r.text)
        assert "\n" not in r.json()["detail"]
    # A mapping names the tracker's shot when the file name does not.
    c = client_for([root], tracker=make("kitsu", _settings(kitsu)), mapping={"sq01_sh999": {"sequence": "sq01",
                                                                                          "shot": "sh010"}})  # fmt: skip
    r = c.post("/api/shots/0/sq01/sq01_sh999/tracker", json={}, headers={"X-CSRF-Token": c.login.csrf})
    assert r.status_code == 200 and r.json()["shot"] == "sh010", r.text


def test_publish_from_the_shell_sends_the_take(kitsu, task, tmp_path):
    """`tween approve` then `tween publish --tracker kitsu`: the published layer, and the take's
    MP4 and note on the shot's animation task."""
    import os

    import gazu

    k = task["client"]
    project = gazu.project.get_project_by_name(PROJECT, client=k)
    seq = gazu.shot.get_sequence_by_name(project, "sq01", client=k)
    anim = gazu.task.get_task_type_by_name("Animation", client=k)
    sh = gazu.task.new_task(gazu.shot.new_shot(project, seq, "sh030", client=k), anim, client=k)
    made = filled_shot(tmp_path / "sq01", "sq01_sh030")
    env = {**os.environ, "TWEEN_KITSU_URL": kitsu.url, "TWEEN_KITSU_USER": ADMIN,
           "TWEEN_KITSU_PASSWORD": PASSWORD, "TWEEN_KITSU_PROJECT": PROJECT}  # fmt: skip
    run = [sys.executable, "-m", "pipeline.cli"]
    r = subprocess.run([*run, "approve", str(made["shot"]), "--take", "0", "--note", "contact fixed"],
                       env=env, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 0, r.stderr
    # The tracker down: the layer is published, the take not sent; the next try sends it (it
    # was refused: "already exists; never overwritten").
    down = {**env, "TWEEN_KITSU_URL": "http://127.0.0.1:1/api"}
    r = subprocess.run([*run, "publish", str(made["shot"]), "--tracker", "kitsu"], env=down, capture_output=True,
                       text=True, timeout=300)  # fmt: skip
    assert r.returncode == 2 and r.stderr.splitlines()[-1].startswith("tween: error: "), r.stderr
    layer = r.stdout.strip()
    assert layer.endswith("sq01_sh030.publish.v002.usda") and os.path.isfile(layer)
    written = os.stat(layer).st_mtime_ns
    r = subprocess.run([*run, "publish", str(made["shot"]), "--tracker", "kitsu"], env=env, capture_output=True,
                       text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert f"{layer}: published already; sending its take" in r.stderr and r.stdout == "", r.stderr
    assert os.stat(layer).st_mtime_ns == written  # never overwritten
    assert "sent take 0 to kitsu: sq01/sh030" in r.stderr, r.stderr
    previews = gazu.files.get_all_preview_files_for_task(sh, client=k)
    assert len(previews) == 1
    assert gazu.task.get_last_comment_for_task(sh, client=k)["text"].startswith("contact fixed")


def test_names_and_settings(tmp_path, monkeypatch):
    from pathlib import Path

    assert names("sq01_sh010", Path("/x/seq")) == ("sq01", "sh010")
    assert names("sh010", Path("/shows/abc/sq03")) == ("sq03", "sh010")
    assert names("sh010", Path("/x"), {"sh010": {"sequence": "A", "shot": "B"}}) == ("A", "B")
    with pytest.raises(TrackerError, match="needs a sequence and a shot"):
        names("sh010", Path("/x"), {"sh010": {"shot": "B"}})
    for k in ("URL", "USER", "PASSWORD", "PROJECT"):
        monkeypatch.delenv(f"TWEEN_KITSU_{k}", raising=False)
    with pytest.raises(TrackerError, match="not configured: set TWEEN_KITSU_URL, TWEEN_KITSU_USER"):
        make("kitsu")
    with pytest.raises(TrackerError, match="unknown tracker"):
        make("shotgun")
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "dailies", str(tmp_path), "--tracker", "kitsu"],
                       capture_output=True, text=True, timeout=60,
                       env={k: v for k, v in __import__("os").environ.items() if not k.startswith("TWEEN_KITSU")})  # fmt: skip
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "kitsu: not configured" in r.stderr
    (tmp_path / "map.json").write_text(json.dumps({"a": 1}).replace("}", ', "a": 2}'))
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "dailies", str(tmp_path), "--tracker", "kitsu",
                        "--tracker-map", str(tmp_path / "map.json")], capture_output=True, text=True, timeout=60)  # fmt: skip
    assert r.returncode == 2 and "given twice" in r.stderr
    # tween publish checks the tracker before it writes anything.
    made = filled_shot(tmp_path / "sq01", "sq01_sh040", takes=1, render=False, frames=13)
    clean = {k: v for k, v in __import__("os").environ.items() if not k.startswith("TWEEN_KITSU")}
    run = [sys.executable, "-m", "pipeline.cli"]
    r = subprocess.run([*run, "approve", str(made["shot"]), "--take", "0"], capture_output=True, text=True,
                       timeout=120, env=clean)  # fmt: skip
    assert r.returncode == 0, r.stderr
    before = sorted(p.name for p in (tmp_path / "sq01").iterdir())
    r = subprocess.run([*run, "publish", str(made["shot"]), "--tracker", "kitsu"], capture_output=True,
                       text=True, timeout=120, env=clean)  # fmt: skip
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "kitsu: not configured" in r.stderr, r.stderr
    assert sorted(p.name for p in (tmp_path / "sq01").iterdir()) == before  # nothing published
    # ... and that the approved take has an MP4 to send (this shot was never rendered).
    configured = {**clean, "TWEEN_KITSU_URL": "http://127.0.0.1:1/api", "TWEEN_KITSU_USER": "a",
                  "TWEEN_KITSU_PASSWORD": "b", "TWEEN_KITSU_PROJECT": "p"}  # fmt: skip
    r = subprocess.run([*run, "publish", str(made["shot"]), "--tracker", "kitsu"], capture_output=True,
                       text=True, timeout=120, env=configured)  # fmt: skip
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "has no review MP4" in r.stderr, r.stderr
    assert sorted(p.name for p in (tmp_path / "sq01").iterdir()) == before
