"""A real Kitsu (zou) for the tracker tests: a private PostgreSQL cluster and Redis, zou in a
venv of its own (``.cache/zou-venv``, made on first use), served by gunicorn on loopback.

Facts and pitfalls: ../shared/notes/kitsu.md. Only a missing PostgreSQL is a skip; anything
else that fails is a test error.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
ZOU_VENV = REPO / ".cache" / "zou-venv"
PG_BIN = Path("/usr/lib/postgresql/15/bin")
ADMIN, PASSWORD = "admin@example.com", "tween-dailies-1"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _pg(name: str) -> str | None:
    found = shutil.which(name)
    return found or (str(PG_BIN / name) if (PG_BIN / name).exists() else None)


_BUILD: subprocess.Popen | None = None
_BUILD_LOG = REPO / ".cache" / "zou-venv.log"
_BUILD_LOCK = REPO / ".cache" / "zou-venv.lock"
#: Written last: a venv without it was interrupted and is made again.
_DONE = ZOU_VENV / ".complete"


def build_zou_venv() -> None:
    """Starts making the zou venv in the background (a pip install that mostly waits on the
    network), so that it overlaps the tests that run before the Kitsu ones; idempotent."""
    global _BUILD
    if _BUILD is not None or _DONE.exists():
        return
    ZOU_VENV.parent.mkdir(parents=True, exist_ok=True)
    # Under a file lock: with pytest-xdist every test process collects the Kitsu tests and
    # asks for the venv; the first makes it, the others wait and find it complete.
    script = (
        f'[ -e "{_DONE}" ] || {{ rm -rf "{ZOU_VENV}" && "{sys.executable}" -m venv "{ZOU_VENV}" && '
        f'"{ZOU_VENV}/bin/pip" install -q zou gazu && touch "{_DONE}"; }} > "{_BUILD_LOG}" 2>&1'
    )
    _BUILD = subprocess.Popen(["flock", str(_BUILD_LOCK), "bash", "-c", script], stdout=subprocess.DEVNULL)


def _zou_venv() -> Path:
    if not _DONE.exists():  # test-time server: kept out of the product's dependencies
        build_zou_venv()
        if _BUILD.wait(timeout=900) != 0:
            raise RuntimeError(f"making {ZOU_VENV} failed: {_BUILD_LOG.read_text()[-2000:]}")
    return ZOU_VENV / "bin"


def _ffmpeg() -> None:
    """zou reads every uploaded movie with ffmpeg/ffprobe: installed with apt when missing."""
    if not shutil.which("ffprobe") and os.geteuid() == 0 and shutil.which("apt-get"):
        env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
        subprocess.run(["apt-get", "install", "-y", "-q", "--no-install-recommends", "ffmpeg"], env=env,
                       capture_output=True, timeout=900)  # fmt: skip
    if not shutil.which("ffprobe"):
        raise RuntimeError("zou needs ffmpeg (apt-get install ffmpeg) to read uploaded previews")


def _as_postgres(cmd: list[str], **kw):
    run_as = ["runuser", "-u", "postgres", "--"] if os.geteuid() == 0 else []
    return subprocess.run(run_as + cmd, check=True, capture_output=True, text=True, **kw)


class KitsuServer:
    """Start with :meth:`start`; ``url`` is the API root for gazu."""

    def __init__(self):
        self.procs: list[subprocess.Popen] = []
        self.work = Path(tempfile.mkdtemp(prefix="tween-kitsu-"))
        self.pgdata = self.work / "pg"
        self.url = ""

    def start(self) -> KitsuServer:
        initdb, pg_ctl = _pg("initdb"), _pg("pg_ctl")
        if not initdb or not pg_ctl:
            pytest.skip("PostgreSQL (initdb, pg_ctl) is not installed: no Kitsu server to test against")
        bin_ = _zou_venv()
        _ffmpeg()
        os.chmod(self.work, 0o755)
        self.pgdata.mkdir()
        sock = self.work / "sock"
        sock.mkdir()
        if os.geteuid() == 0:
            shutil.chown(self.pgdata, "postgres")
            shutil.chown(sock, "postgres")
        pg_port, kv_port, port = _free_port(), _free_port(), _free_port()
        _as_postgres([initdb, "-D", str(self.pgdata), "-U", "postgres", "-A", "trust"], timeout=120)
        opts = f"-p {pg_port} -k {sock} -c listen_addresses=127.0.0.1 -c fsync=off"
        _as_postgres([pg_ctl, "-D", str(self.pgdata), "-o", opts, "-l", str(self.pgdata / "log"), "-w", "start"],
                     timeout=120)  # fmt: skip
        psql = [
            "psql",
            "-h",
            "127.0.0.1",
            "-p",
            str(pg_port),
            "-U",
            "postgres",
            "-v",
            "ON_ERROR_STOP=1",
            "-c",
        ]
        subprocess.run(
            [*psql, "CREATE ROLE zou LOGIN SUPERUSER PASSWORD 'zou'"], check=True, capture_output=True
        )
        subprocess.run([*psql, "CREATE DATABASE zou OWNER zou"], check=True, capture_output=True)
        self.procs.append(subprocess.Popen(
            ["redis-server", "--port", str(kv_port), "--bind", "127.0.0.1", "--save", "", "--appendonly", "no"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        ))  # fmt: skip
        env = dict(os.environ, DB_HOST="127.0.0.1", DB_PORT=str(pg_port), DB_USERNAME="zou", DB_PASSWORD="zou",
                   DB_DATABASE="zou", KV_HOST="127.0.0.1", KV_PORT=str(kv_port),
                   PREVIEW_FOLDER=str(self.work / "previews"), TMP_DIR=str(self.work / "tmp"),
                   SECRET_KEY="tween-dailies-test-secret-key-0123456789", MAIL_ENABLED="false",
                   # an existing but empty folder stops zou booting: a path that does not exist
                   EVENT_HANDLERS_FOLDER=str(self.work / "no-event-handlers"),
                   MOVIE_ENCODING_PRESET="ultrafast", SKIP_NORMALIZATION_HIGHDEF="true",
                   PATH=f"{bin_}:{os.environ['PATH']}")  # fmt: skip
        (self.work / "tmp").mkdir()
        for args in (["init-db"], ["init-data"], ["create-admin", ADMIN, "--password", PASSWORD]):
            subprocess.run([str(bin_ / "zou"), *args], env=env, cwd=self.work, check=True, capture_output=True,
                           timeout=300)  # fmt: skip
        self.log = open(self.work / "zou.log", "w")
        self.procs.append(subprocess.Popen(
            [str(bin_ / "gunicorn"), "-b", f"127.0.0.1:{port}", "-w", "1", "--no-control-socket", "-t", "300",
             "zou.app:create_app()"], env=env, cwd=self.work, stdout=self.log, stderr=subprocess.STDOUT,
        ))  # fmt: skip
        self.url = f"http://127.0.0.1:{port}"
        for _ in range(300):
            try:
                urllib.request.urlopen(self.url, timeout=2)
                return self
            except urllib.error.HTTPError:
                return self  # it answers
            except OSError:
                if self.procs[-1].poll() is not None:
                    raise RuntimeError(f"zou exited: {(self.work / 'zou.log').read_text()[-2000:]}") from None
                time.sleep(0.1)
        raise RuntimeError("zou did not answer within 30 s")

    def stop(self) -> None:
        for p in reversed(self.procs):
            p.send_signal(signal.SIGTERM)
            try:
                p.wait(15)
            except subprocess.TimeoutExpired:
                p.kill()
        if self.pgdata.exists():
            try:
                _as_postgres([_pg("pg_ctl"), "-D", str(self.pgdata), "-m", "fast", "stop"], timeout=60)
            except subprocess.CalledProcessError:
                pass
        shutil.rmtree(self.work, ignore_errors=True)
