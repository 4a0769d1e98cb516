"""The farm's jobs for the shots, on the page: queued, failed with its reason, cancelled from
the page (nothing of it kept). A real Redis farm and a real worker."""

import json
import os
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
from redis_server import WorkerPool, farm_env, start_redis

TOKEN = "f" * 40


@pytest.fixture
def redis():
    server = start_redis()
    yield server
    server.cleanup()


def _api(base, path, method="GET"):
    req = urllib.request.Request(base + path, method=method, headers={"Authorization": f"Bearer {TOKEN}"})
    for _ in range(100):
        try:
            with urllib.request.urlopen(req, timeout=60) as r:
                return r.status, json.loads(r.read())
        except urllib.error.HTTPError as e:
            return e.code, json.loads(e.read())
        except urllib.error.URLError:
            time.sleep(0.1)
    raise AssertionError(f"{path}: no answer")


def _post(base, path, body):
    req = urllib.request.Request(base + path, method="POST", data=json.dumps(body).encode(),
                                 headers={"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"})  # fmt: skip
    try:
        with urllib.request.urlopen(req, timeout=60) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read())


def test_jobs_listed_failed_and_cancelled(redis, roots, tmp_path):
    from usd_fixtures import bandai_shot

    folder = roots[0] / "seq03"
    folder.mkdir()
    keep = bandai_shot(folder / "sh070.usda", frames=21)
    gone = bandai_shot(folder / "sh080.usda", frames=21)
    env = {**os.environ, **farm_env(redis, [str(roots[0])])}
    sub = subprocess.run([sys.executable, "-m", "pipeline.cli", "submit", str(keep), str(gone), "--model", "interp"],
                         env=env, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert sub.returncode == 0, sub.stderr
    keep_id, gone_id = sub.stdout.split()
    gone.unlink()  # the worker will find no shot: a failure with its reason
    server = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "dailies", str(roots[0]), "--port", "0",
                               "--token", TOKEN], env=env, stdout=subprocess.PIPE, text=True)  # fmt: skip
    try:
        base = server.stdout.readline().strip().split("/?token=")[0]
        status, out = _api(base, "/api/jobs")
        assert status == 200 and out["note"] is None, out
        assert {(j["id"], j["state"]) for j in out["jobs"]} == {(keep_id, "QUEUED"), (gone_id, "QUEUED")}
        assert {j["shot"] for j in out["jobs"]} == {str(keep), str(gone)}
        status, one = _api(base, "/api/jobs?shot=0/seq01/sh010")  # a shot page shows its own jobs only
        assert status == 200 and one["jobs"] == []
        assert _api(base, "/api/jobs?shot=0/seq03/sh070")[0] == 404  # no fill yet: no shot page
        # Cancelled from the page while queued: it never runs, even on a worker started later.
        status, row = _api(base, f"/api/jobs/{keep_id}/cancel", "POST")
        assert status == 200 and row["state"] == "CANCELLED", row
        assert _api(base, f"/api/jobs/{keep_id}/cancel", "POST")[0] == 409  # already cancelled
        assert _api(base, "/api/jobs/" + "0" * 32 + "/cancel", "POST")[0] == 404
        pool = WorkerPool(farm_env(redis, [str(roots[0])]), tmp_path)
        pool.start()
        try:
            pool.wait_ready(120)
            t0 = time.monotonic()
            while True:
                out = _api(base, "/api/jobs")[1]
                states = {j["id"]: j for j in out["jobs"]}
                if states.get(gone_id, {}).get("state") == "FAILURE":
                    break
                assert time.monotonic() - t0 < 120, out
                time.sleep(0.5)
        finally:
            pool.stop_all()
        why = states[gone_id]["error"]
        assert "sh080.usda" in why and "\n" not in why, why
        assert states[keep_id]["state"] == "CANCELLED"
        assert not list(folder.glob("sh070.tween.v*"))  # nothing of the cancelled job
    finally:
        server.send_signal(signal.SIGINT)
        server.wait(30)


def test_no_farm_is_said(client):
    out = client.get("/api/jobs").json()
    assert out["jobs"] == [] and "no farm configured" in out["note"]
    r = client.post("/api/jobs/" + "a" * 32 + "/cancel", headers={"X-CSRF-Token": client.login.csrf})
    assert r.status_code == 409 and "no farm configured" in r.json()["detail"]


def test_render_from_the_page(redis, tmp_path):
    """A fill without renders: "render" sends one render-only job for its takes; refused while
    one is on the farm; cancelled, it leaves the version as it was; run, the takes have their
    turntables and the page shows them; refused once rendered."""
    from dailies_fixtures import filled_shot

    root = tmp_path / "shots"
    made = filled_shot(root / "seq05", "sh090", takes=2, render=False, frames=13)
    layers = sorted(p.name for p in (root / "seq05").iterdir())
    env = {**os.environ, **farm_env(redis, [str(root)])}
    server = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "dailies", str(root), "--port", "0",
                               "--token", TOKEN], env=env, stdout=subprocess.PIPE, text=True)  # fmt: skip
    key = "0/seq05/sh090"
    try:
        base = server.stdout.readline().strip().split("/?token=")[0]
        status, shot = _api(base, f"/api/shots/{key}")
        assert status == 200 and [t["mp4"] for t in shot["takes"]] == [None, None], shot
        status, first = _post(base, f"/api/shots/{key}/render", {"version": shot["version"]})
        assert status == 200 and first["state"] == "QUEUED" and first["total"] == 1, first
        status, again = _post(base, f"/api/shots/{key}/render", {"version": shot["version"]})
        assert status == 409 and "already rendering" in again["detail"] and first["id"] in again["detail"]
        status, row = _api(base, f"/api/jobs/{first['id']}/cancel", "POST")
        assert status == 200 and row["state"] == "CANCELLED", row
        assert sorted(p.name for p in (root / "seq05").iterdir()) == layers  # the version stays
        status, job = _post(base, f"/api/shots/{key}/render", {"version": shot["version"]})
        assert status == 200 and job["state"] == "QUEUED", job
        assert [j["id"] for j in _api(base, f"/api/jobs?shot={key}")[1]["jobs"]][0] == job["id"]
        pool = WorkerPool(farm_env(redis, [str(root)]), tmp_path)
        pool.start()
        try:
            pool.wait_ready(120)
            t0 = time.monotonic()
            while not all(t["mp4_url"] for t in _api(base, f"/api/shots/{key}")[1]["takes"]):
                jobs = {j["id"]: j for j in _api(base, "/api/jobs")[1]["jobs"]}
                assert jobs.get(job["id"], {}).get("state") != "FAILURE", jobs[job["id"]]
                assert time.monotonic() - t0 < 240, jobs
                time.sleep(0.5)
        finally:
            pool.stop_all()
        review = root / "seq05" / "review"
        assert {p.name for p in review.glob("*.mp4")} == {"sh090_v001_take0.mp4", "sh090_v001_take1.mp4"}
        assert (review / "sh090_v001.otio").is_file()
        assert not list(review.glob(".tween-review-*"))  # no scratch left
        assert Path(made["layer"]).is_file() and Path(made["review"]).is_file()
        status, done = _post(base, f"/api/shots/{key}/render", {"version": shot["version"]})
        assert status == 409 and "rendered already" in done["detail"], done
    finally:
        server.send_signal(signal.SIGINT)
        server.wait(30)


def test_render_without_a_farm_says_how(roots):
    from dailies_fixtures import client_for, filled_shot

    filled_shot(roots[0] / "seq06", "sh100", takes=1, render=False, frames=13)
    client = client_for(roots)
    r = client.post("/api/shots/0/seq06/sh100/render", json={}, headers={"X-CSRF-Token": client.login.csrf})
    assert r.status_code == 409, r.text
    assert "no farm configured" in r.json()["detail"] and "tween review " in r.json()["detail"]
    r = client.post("/api/shots/0/seq01/sh010/render", json={}, headers={"X-CSRF-Token": client.login.csrf})
    assert r.status_code == 409 and "rendered already" in r.json()["detail"], r.text  # its takes have media
    page = client.get("/shot/0/seq06/sh100").text
    assert 'data-action="render"' in page
