"""Faults (issue 17): a killed client or writer, concurrent writers of one job, a full disk or
a too large file, refusals, and shots given through a symlink.

Each test makes its own conditions: processes it kills, a 2 MB tmpfs it mounts (when this
host lets it; else the same failure is simulated), RLIMIT_FSIZE in a child process (a real
EFBIG).
"""

from __future__ import annotations

import errno
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from redis_server import REPO, copy_shot, example_shot

from pipeline.errors import TweenError
from pipeline.fill.api import FillOptions, fill_shot, fill_take
from pipeline.usd import files, write
from pipeline.usd.files import HOST as _HOST
from pipeline.usd.files import pid_alive

TESTS = Path(__file__).resolve().parents[1]
STEM = "sh010_walk"

# Loaded by every Python process of a test run: slow fills (farm_slowfill) and a writer that
# hangs after saving its temp layer and before linking it (so the test can kill it mid-save).
HOOKS = """
import os
if os.environ.get("TWEEN_TEST_SLOW_FILL"):
    import farm_slowfill  # noqa: F401
if os.environ.get("TWEEN_TEST_FAIL_TAKE"):
    from pipeline.fill import api as _f
    from pipeline.errors import ShotError
    def _fail(shot, *a, **k):
        raise ShotError(shot, "refused by the test")
    _f.fill_take = _fail
if os.environ.get("TWEEN_TEST_HANG_SAVE"):
    import time
    from pipeline.usd import files as _w
    _real = _w.link_new
    def _hang(tmp, final):
        if ".tween." in final.name:
            with open(os.environ["TWEEN_TEST_HANG_SAVE"], "w") as f:
                f.write(str(tmp))
            time.sleep(120)
        return _real(tmp, final)
    _w.link_new = _hang
"""


def _env(tmp_path: Path, **extra) -> dict:
    hooks = tmp_path / "hooks"
    hooks.mkdir(exist_ok=True)
    (hooks / "sitecustomize.py").write_text(HOOKS)
    env = {k: v for k, v in os.environ.items() if not k.startswith("TWEEN_")}
    env.update(
        TWEEN_CACHE=str(tmp_path / "cache"),
        TWEEN_FARM_CONFIG=os.devnull,
        PYTHONPATH=os.pathsep.join([str(hooks), str(TESTS), str(REPO)]),
    )
    if "TWEEN_DATA" in os.environ:
        env["TWEEN_DATA"] = os.environ["TWEEN_DATA"]
    env.update({k: str(v) for k, v in extra.items()})
    return env


def _shot(tmp_path: Path, folder: str = "shots") -> Path:
    return copy_shot(example_shot(), tmp_path / folder, STEM)


def _cli(*args) -> list[str]:
    return [sys.executable, "-m", "pipeline.cli", *map(str, args)]


def _fill_local(shot, out, env, *args, fsize: int | None = None, timeout=120):
    cmd = _cli("fill-local", shot, "--model", "interp", *(["--out", out] if out else []), *args)
    pre = None
    if fsize is not None:

        def pre():  # a real EFBIG (SIGXFSZ ignored, so write() fails instead of killing)
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

    return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout, preexec_fn=pre)


def _errors(stderr: str) -> list[str]:
    return [ln for ln in stderr.splitlines() if ln.startswith("tween: error:")]


def _assert_one_line(res, message: str) -> None:
    """Exit 2, exactly one error line (``message``), and none of USD's diagnostics."""
    assert res.returncode == 2, res.stderr[-3000:]
    assert _errors(res.stderr) == [f"tween: error: {message}"], res.stderr[-3000:]
    noise = [ln for ln in res.stderr.splitlines() if not ln.startswith("tween:")]
    assert not noise, noise[:5]


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    assert not pid_alive(p.pid)
    return p.pid


def _descendants(pid: int) -> list[int]:
    children: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(d.name))
    out, todo = [], [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            out.append(c)
            todo.append(c)
    return out


def _wait_for(pred, timeout: float, what: str):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        v = pred()
        if v:
            return v
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.fixture
def tmpfs(tmp_path):
    """A 2 MB tmpfs, or None where this host does not let the test mount one."""
    d = tmp_path / "tmpfs"
    d.mkdir()
    try:
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(d)], capture_output=True)
    except OSError:
        r = None
    if r is None or r.returncode != 0:
        yield None
        return
    try:
        yield d
    finally:
        subprocess.run(["umount", "-l", str(d)], capture_output=True)


def _fill_up(folder: Path, leave: int) -> None:
    """Leaves about ``leave`` bytes free on ``folder``'s file system (0: none at all)."""
    left = shutil.disk_usage(folder).free - leave if leave else 1 << 40
    try:
        with open(folder / "filler", "ab", buffering=0) as f:
            while left > 0:
                left -= f.write(b"\0" * min(left, 1 << 16))
    except OSError as e:
        assert e.errno == errno.ENOSPC


# --- kills ---------------------------------------------------------------------------------


def test_sigkill_of_fill_client_leaves_no_worker_and_next_run_cleans(tmp_path):
    shot = _shot(tmp_path)
    markers = tmp_path / "markers"
    markers.mkdir()
    env = _env(tmp_path, TWEEN_TEST_SLOW_FILL=1, TWEEN_TEST_FILL_DELAY=120, TWEEN_TEST_MARKERS=markers)
    with open(tmp_path / "client.log", "wb") as log:
        client = subprocess.Popen(_cli("fill", shot, "--model", "interp", "--no-progress"), env=env,
                                  stdout=log, stderr=log)  # fmt: skip
    kids: list[int] = []
    try:
        _wait_for(lambda: list(markers.iterdir()), 90, "the slow take to start")
        kids = _descendants(client.pid)
        assert len(kids) >= 2, kids  # the worker and its pool child
        client.kill()
        client.wait()
        t0 = time.monotonic()
        while time.monotonic() - t0 < 5 and any(pid_alive(k) for k in kids):
            time.sleep(0.05)
        assert not [k for k in kids if pid_alive(k)], "embedded worker outlived its client"
    finally:
        if client.poll() is None:
            client.kill()
        for k in kids:
            if pid_alive(k):
                os.kill(k, signal.SIGKILL)
    # The killed job's work folder is the dead client's: the next run into the folder drops it.
    work = shot.parent / ".tween-work"
    assert work.is_dir() and list(work.iterdir())
    env = _env(tmp_path)
    res = subprocess.run(_cli("fill", shot, "--model", "interp", "--no-progress"), env=env,
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert res.returncode == 0, res.stderr[-3000:]
    assert not work.exists()
    assert (shot.parent / f"{STEM}.tween.v001.usda").is_file()


def test_kill_during_save_leaves_temps_the_next_run_removes(tmp_path):
    shot = _shot(tmp_path)
    out, systmp = tmp_path / "out", tmp_path / "systmp"
    systmp.mkdir()
    hang = tmp_path / "hang"
    env = _env(tmp_path, TMPDIR=systmp)
    cmd = _cli("fill-local", shot, "--model", "interp", "--out", out)
    p = subprocess.Popen(cmd, env=dict(env, TWEEN_TEST_HANG_SAVE=hang), stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)  # fmt: skip
    try:
        _wait_for(hang.exists, 60, "the layer save")
        time.sleep(0.2)
    finally:
        p.kill()
        p.wait()
    left = sorted(x.name for x in out.iterdir())
    # The lock file of the killed writer stays too (the next writer locks it, and removes it),
    # and the review layer it wrote before the fill layer: no fill layer, so no version.
    assert left == sorted([f".{STEM}.tween.v001.{p.pid}@{_HOST}.tmp.usda", f".{STEM}.tween.lock",
                           f"{STEM}.review.v001.usda"]), left  # fmt: skip
    (take_dir,) = systmp.iterdir()
    assert take_dir.name.startswith(f"tween-take.{p.pid}@") and list(take_dir.glob("*.npz"))
    # Also: a temp of the earlier naming by a dead pid (removed), a live writer's and another
    # host's (both kept).
    old = out / f".{STEM}.tween.v002.{_dead_pid()}.tmp.usda"
    live = out / f".{STEM}.tween.v003.{os.getpid()}@{_HOST}.tmp.usda"
    other = out / f".{STEM}.tween.v004.{p.pid}@elsewhere.tmp.usda"
    for f in (old, live, other):
        f.write_text("#usda 1.0\n")
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-3000:]
    assert f"removed 3 file(s) a dead writer left in {out}" in res.stderr  # the review of no fill too
    assert sorted(x.name for x in out.glob(f"{STEM}.*")) == [
        f"{STEM}.review.v001.usda",
        f"{STEM}.tween.v001.usda",
    ]
    assert sorted(x.name for x in out.iterdir()) == sorted(
        [live.name, other.name, f"{STEM}.tween.v001.usda", f"{STEM}.review.v001.usda"]
    )
    assert list(systmp.iterdir()) == []


def test_fill_take_removes_dead_npz_temps(tmp_path):
    shot = _shot(tmp_path)
    work = tmp_path / "work"
    work.mkdir()
    dead = work / f".{STEM}.take000.0123456789abcdef.npz.{_dead_pid()}@{_HOST}.k2j4h5g6.tmp"
    live = work / f".{STEM}.take001.0123456789abcdef.npz.{os.getpid()}@{_HOST}.a1b2c3d4.tmp"
    dead.write_bytes(b"partial")
    live.write_bytes(b"partial")
    path = Path(fill_take(str(shot), FillOptions(model="interp"), 0, str(work)))
    assert sorted(work.iterdir()) == sorted([path, live])


# --- concurrency ---------------------------------------------------------------------------


def test_one_job_id_gives_one_layer_under_concurrent_writers(tmp_path):
    shot = _shot(tmp_path)
    out = tmp_path / "out"
    env = _env(tmp_path)
    for job, n in (("J1", 4), ("J2", 3)):
        cmd = _cli("fill-local", shot, "--model", "interp", "--job-id", job, "--out", out)
        procs = [subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                 for _ in range(n)]  # fmt: skip
        results = []
        for p in procs:
            o, e = p.communicate(timeout=120)
            assert p.returncode == 0, e[-2000:]
            results.append(json.loads(o))
        assert len({(r["layer"], r["review"], r["version"]) for r in results}) == 1, results
    from pxr import Sdf

    ids = {}
    for p in out.glob(f"{STEM}.tween.v*.usda"):
        ids[p.name] = Sdf.Layer.OpenAsAnonymous(str(p)).customLayerData["tween"]["jobId"]
    assert ids == {f"{STEM}.tween.v001.usda": "J1", f"{STEM}.tween.v002.usda": "J2"}
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [*ids, f"{STEM}.review.v001.usda", f"{STEM}.review.v002.usda"]
    )  # no lock file and no temp left


# --- full disk, file too large -------------------------------------------------------------


def test_disk_full_writing_the_layer(tmp_path, tmpfs, monkeypatch):
    shot = _shot(tmp_path)
    if tmpfs is None:  # no mount here: the same failure, simulated in process
        out = tmp_path / "out"

        def full(*a, **k):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        monkeypatch.setattr(write, "author_fill_layer", full)
        with pytest.raises(TweenError, match=r"tween\.v001\.usda: no space left on device$"):
            fill_shot(str(shot), FillOptions(model="interp", out_dir=str(out)))
        assert not out.exists()
        return
    _fill_up(tmpfs, 40_000)  # the layer is ~190 kB
    out = tmpfs / "shots" / "out"
    for fmt in ("usda", "usdc"):
        if fmt == "usdc":
            _fill_up(tmpfs, 8_000)
        res = _fill_local(shot, out, _env(tmp_path), "--format", fmt)
        _assert_one_line(res, f"{out}/{STEM}.tween.v001.{fmt}: no space left on device")
        assert sorted(p.name for p in tmpfs.iterdir()) == ["filler"]  # no folder, temp or layer


def test_file_too_large_writing_the_layer(tmp_path):
    shot = _shot(tmp_path)
    out = tmp_path / "out"
    # The take (~77 kB) fits under the limit; the layer (~190 kB) does not.
    res = _fill_local(shot, out, _env(tmp_path, TMPDIR=tmp_path), fsize=120_000)
    _assert_one_line(res, f"{out}/{STEM}.tween.v001.usda: file too large")
    assert not out.exists()
    assert not list(tmp_path.glob("tween-take.*"))


def test_disk_full_writing_the_review_layer(tmp_path, tmpfs, monkeypatch, capfd):
    shot = _shot(tmp_path)
    base = tmpfs or tmp_path
    out = base / "out"
    real, real_review = files.link_new, write.write_review

    def then_full(tmp, final):
        if ".review." in final.name and tmpfs is None:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(tmp, final)

    def full_review(*args):  # the fill layer is saved (its temp): nothing is left for the review
        _fill_up(tmpfs, 0)
        return real_review(*args)

    monkeypatch.setattr(files, "link_new", then_full)
    if tmpfs is not None:
        monkeypatch.setattr(write, "write_review", full_review)
    with pytest.raises(TweenError) as e:
        fill_shot(str(shot), FillOptions(model="interp", out_dir=str(out)))
    assert str(e.value) == f"{out}/{STEM}.review.v001.usda: no space left on device"
    assert not out.exists()  # no review temp, no fill layer, no folder
    if tmpfs is not None:
        assert sorted(p.name for p in tmpfs.iterdir()) == ["filler"]
    assert "Error" not in capfd.readouterr().err


def test_disk_full_and_too_large_writing_a_take(tmp_path, tmpfs, monkeypatch):
    shot = _shot(tmp_path)
    # EFBIG: the take is the first file written (~77 kB).
    systmp = tmp_path / "systmp"
    systmp.mkdir()
    out = tmp_path / "out"
    res = _fill_local(shot, out, _env(tmp_path, TMPDIR=systmp), fsize=30_000)
    assert res.returncode == 2, res.stderr[-3000:]
    (line,) = _errors(res.stderr)
    assert line == (
        f"tween: error: {systmp}: the system temp folder is full (file too large) while filling the takes of "
        f"{shot}; free space there, or set TMPDIR to a folder with room, and run again"
    ), line
    assert list(systmp.iterdir()) == [] and not out.exists()
    # ENOSPC: a take written to a full folder.
    work = (tmpfs or tmp_path) / "work"
    if tmpfs is None:

        def full(*a, **k):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        monkeypatch.setattr("numpy.savez", full)
    else:
        work.mkdir()
        _fill_up(tmpfs, 0)
    with pytest.raises(TweenError, match=r"\.npz: no space left on device$"):
        fill_take(str(shot), FillOptions(model="interp"), 0, str(work))
    assert not list(work.iterdir())


def test_disk_full_and_too_large_converting(tmp_path, tmpfs, bandai_clip, monkeypatch):
    env = _env(tmp_path)
    pre_cmd = _cli("convert", bandai_clip, tmp_path / "warm.usda", "--frames", "0-30")
    assert subprocess.run(pre_cmd, env=env, capture_output=True, timeout=120).returncode == 0  # caches
    folder = tmp_path / "conv"
    folder.mkdir()
    out = folder / "shot.usda"

    def pre():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))

    cmd = _cli("convert", bandai_clip, out, "--frames", "0-30")
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120, preexec_fn=pre)
    _assert_one_line(res, f"{out}: file too large")
    assert list(folder.iterdir()) == []
    if tmpfs is None:
        from pipeline.motion.bvh import read_bvh
        from pipeline.usd import convert

        def full(*a, **k):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        monkeypatch.setattr(convert.os, "replace", full)  # the final rename of the saved temp
        with pytest.raises(TweenError, match=r"shot\.usda: no space left on device$"):
            convert.write_shot(read_bvh(bandai_clip).slice(0, 31), out)
        assert list(folder.iterdir()) == []
        return
    _fill_up(tmpfs, 8_000)
    out = tmpfs / "shot.usda"
    res = subprocess.run(_cli("convert", bandai_clip, out, "--frames", "0-30"), env=env, capture_output=True,
                         text=True, timeout=120)  # fmt: skip
    _assert_one_line(res, f"{out}: no space left on device")
    assert sorted(p.name for p in tmpfs.iterdir()) == ["filler"]


# --- refusals, symlinks --------------------------------------------------------------------


def test_refusal_creates_no_output_folder(tmp_path):
    shot = _shot(tmp_path)
    new = tmp_path / "new"
    res = _fill_local(shot, new / "nested", _env(tmp_path), "--review-layer", shot)
    assert res.returncode == 2 and len(_errors(res.stderr)) == 1, res.stderr[-2000:]
    assert "animator's layers are never modified" in res.stderr
    assert not new.exists()
    assert sorted(p.name for p in shot.parent.iterdir()) == [shot.name]


def test_farm_refusal_after_the_take_folder_was_made_leaves_no_output_folder(tmp_path):
    # The farm's take folder is beside the layers (<out>/.tween-work/<job>): a job that fails
    # removes the output folders that did not exist when it was submitted.
    shot = _shot(tmp_path)
    new = tmp_path / "new"
    env = _env(tmp_path, TWEEN_TEST_FAIL_TAKE=1)
    cmd = _cli("fill", shot, "--model", "interp", "--out-dir", new / "nested", "--no-progress")
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 2, res.stderr[-2000:]
    assert _errors(res.stderr) == [f"tween: error: {shot}: refused by the test"], res.stderr[-2000:]
    assert not new.exists()


def test_symlinked_shot_gets_its_layers_beside_the_link(tmp_path):
    from pxr import Usd

    shot = _shot(tmp_path, "published")
    seq = tmp_path / "seq"
    seq.mkdir()
    link = seq / "sh020.usda"
    link.symlink_to(shot)
    res = _fill_local(link, None, _env(tmp_path))
    assert res.returncode == 0, res.stderr[-3000:]
    r = json.loads(res.stdout)
    assert Path(r["layer"]) == seq / "sh020.tween.v001.usda"
    assert Path(r["review"]) == seq / "sh020.review.v001.usda"
    assert sorted(p.name for p in shot.parent.iterdir()) == [shot.name]  # nothing beside the target
    from pxr import Sdf

    review = Sdf.Layer.FindOrOpen(r["review"])
    assert list(review.subLayerPaths) == ["sh020.tween.v001.usda", "sh020.usda"]
    stage = Usd.Stage.Open(r["review"])
    anim = stage.GetPrimAtPath("/World/Walker/Skel/Anim_tween")
    assert anim and anim.GetAttribute("rotations").GetTimeSamples()
