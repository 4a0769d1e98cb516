"""A farm whose broker misbehaves: one that accepts connections and never answers (a stopped
Redis) and one that answers slowly, one lost while `tween fill` waits, a stage killed at its
hard limit after its heartbeats stopped, and the embedded farm's SQLite stores on a full disk.
Each is one line on stderr and exit status 2."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import threading
import time
import uuid

import pytest
from redis_server import REPO, configure_app, start_redis


def _tween(*args, env: dict, timeout: float = 60) -> subprocess.CompletedProcess:
    full = {k: v for k, v in os.environ.items() if not k.startswith("TWEEN_")}
    full.update(env, TWEEN_FARM_CONFIG=os.devnull)
    if "TWEEN_DATA" in os.environ:
        full["TWEEN_DATA"] = os.environ["TWEEN_DATA"]
    cmd = [sys.executable, "-m", "pipeline.cli", *map(str, args)]
    return subprocess.run(cmd, env=full, cwd=REPO, capture_output=True, text=True, timeout=timeout)


class _Server:
    """A TCP server on a free port: ``silent`` accepts and never replies; otherwise it relays
    to ``upstream`` (host, port), holding every reply ``delay`` s. With ``quiet_at`` it goes
    silent mid-command, on every connection, at the first request holding those bytes (not
    relayed), or with ``answered`` just after it (relayed and answered)."""

    def __init__(self, upstream=None, delay: float = 0.0, quiet_at: bytes = b"", answered: bool = False):
        self.upstream, self.delay, self.socks = upstream, delay, []
        self.quiet_at, self.answered = quiet_at, answered
        self.quiet, self.armed = threading.Event(), threading.Event()
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self.sock.accept()
            except OSError:
                return
            self.socks.append(client)  # held open, never answered when silent
            if self.upstream:
                up = socket.create_connection(self.upstream)
                self.socks.append(up)
                threading.Thread(target=self._pipe, args=(client, up, 0.0, True), daemon=True).start()
                threading.Thread(target=self._pipe, args=(up, client, self.delay), daemon=True).start()

    def _pipe(self, src, dst, delay: float, request: bool = False) -> None:
        try:
            while data := src.recv(65536):
                if request and self.armed.is_set():
                    self.quiet.set()
                if request and self.quiet_at and self.quiet_at in data:
                    (self.armed if self.answered else self.quiet).set()
                if self.quiet.is_set():
                    continue  # held, never answered
                time.sleep(delay)
                dst.sendall(data)
        except OSError:
            pass

    def close(self) -> None:
        for s in [self.sock, *self.socks]:
            s.close()


@pytest.fixture
def silent():
    s = _Server()
    yield s
    s.close()


def _lines(r: subprocess.CompletedProcess) -> list[str]:
    return [ln for ln in r.stderr.replace("\r", "\n").splitlines() if ln.strip()]


def test_a_broker_that_never_answers_is_one_line_in_seconds(silent):
    url = f"redis://127.0.0.1:{silent.port}/0"
    t0 = time.monotonic()
    r = _tween("status", "abc", env={"TWEEN_BROKER_URL": url}, timeout=40)
    took = time.monotonic() - t0
    assert r.returncode == 2, r.stderr[-2000:]
    assert _lines(r) == [
        f"tween: error: broker {url}: did not answer within 8 s (it accepts the connection but sends "
        "nothing back: a stopped, wedged or overloaded server?) (the URL comes from TWEEN_BROKER_URL or "
        "the farm config)"
    ]
    assert took < 20


@pytest.mark.parametrize("check", ["check_broker", "check_backend"])
def test_the_checks_give_up_on_a_silent_server(silent, check):
    from celery import Celery

    import workers.app as wa
    from workers.errors import FarmConnectionError
    from workers.settings import load_settings

    url = f"redis://127.0.0.1:{silent.port}/0"
    s = load_settings({"TWEEN_FARM_CONFIG": os.devnull, "TWEEN_BROKER_URL": url})
    app = wa.configure(Celery("tween-silent", set_as_current=False), s)
    t0 = time.monotonic()
    with pytest.raises(FarmConnectionError, match=r"did not answer within 1\.5 s"):
        getattr(wa, check)(app, within=1.5)
    assert time.monotonic() - t0 < 5


def test_a_slow_broker_that_answers_still_works():
    """Every reply held 0.5 s (the first request, the check's, included): slow, not dead."""
    server = start_redis()
    slow = _relay(server, delay=0.5)
    try:
        url = f"redis://127.0.0.1:{slow.port}/0"
        env = {"TWEEN_BROKER_URL": url, "TWEEN_KEY_PREFIX": server.prefix}
        r = _tween("status", "nosuchjob", env=env, timeout=60)
    finally:
        slow.close()
        server.cleanup()
    assert r.returncode == 2, r.stderr[-2000:]
    assert _lines(r) == ["tween: error: nosuchjob: no such job (unknown id, or its record expired)"]


@pytest.fixture
def redis_farm(tmp_path):
    """A real Redis for one test (its own key prefix and queue), and a shot under the roots."""
    server = start_redis()
    shot = tmp_path / "sh010.usda"
    shutil.copyfile(REPO / "examples" / "sh010_walk.usda", shot)
    env = {"TWEEN_KEY_PREFIX": server.prefix, "TWEEN_QUEUE": f"{server.prefix}fill",
           "TWEEN_SHOT_ROOTS": str(tmp_path), "TWEEN_REPLY_TIMEOUT": "1"}  # fmt: skip
    yield server, shot, env
    server.cleanup()


def _relay(server, **kw) -> _Server:
    host, port = server.url.split("//")[1].split("/")[0].split(":")
    return _Server((host, int(port)), **kw)


def _through_relay(redis_farm, command: str, **kw):
    """``tween COMMAND SHOT --model interp`` with the broker behind a relay (``_Server``'s
    ``kw``): the result, the relay's URL, the seconds it took, and the (closed) relay."""
    server, shot, env = redis_farm
    relay = _relay(server, **kw)
    url = f"redis://127.0.0.1:{relay.port}/0"
    try:
        t0 = time.monotonic()
        r = _tween(command, shot, "--model", "interp", env={**env, "TWEEN_BROKER_URL": url}, timeout=60)
        took = time.monotonic() - t0
    finally:
        relay.close()
    return r, url, took, relay


def test_submit_to_a_broker_gone_silent_mid_command_is_one_line(redis_farm):
    """The start-up check answered; the publish never is: kombu waited for ever (a hung
    `tween submit`, deaf to SIGTERM while it sent). Now reply_timeout bounds it."""
    r, url, took, relay = _through_relay(redis_farm, "submit", quiet_at=b"tween.validate")
    assert relay.quiet.is_set()  # it did go silent mid-command, after the check
    assert r.returncode == 2 and r.stdout == "", r.stderr[-2000:]
    assert _lines(r) == [
        f"tween: error: broker {url}: stopped answering (no reply within reply_timeout, 1 s: a stopped, "
        "wedged or overloaded server?) (the URL comes from TWEEN_BROKER_URL or the farm config)"
    ]
    assert took < 20


@pytest.mark.parametrize(
    "command, signum",
    [(["submit"], "SIGINT"), (["fill", "--no-progress"], "SIGTERM")],
    ids=["submit", "fill"],
)
def test_a_signal_while_jobs_are_sent_to_a_silent_broker_ends_it_at_once(redis_farm, command, signum):
    """The broker went silent at the publish, its result backend answering: SIGINT (or
    SIGTERM) was counted, not acted on, and `tween submit` (and a farm `tween fill`) waited
    out reply_timeout, then failed, the job's record left "queued" for ever. Now the signal
    ends it at once, exit 130, and the job it had begun to send is cancelled (whatever of it
    reaches the farm)."""
    import signal

    from typer.testing import CliRunner

    from pipeline.cli import app as cli
    from workers import jobs
    from workers.app import app
    from workers.settings import load_settings

    sig = getattr(signal, signum)
    server, shot, env = redis_farm
    relay = _relay(server, quiet_at=b"tween.validate")
    env = {**env, "TWEEN_FARM_CONFIG": os.devnull, "TWEEN_BROKER_URL": f"redis://127.0.0.1:{relay.port}/0",
           "TWEEN_RESULT_BACKEND": server.url, "TWEEN_REPLY_TIMEOUT": "8"}  # fmt: skip
    old, running = app.conf.tween, threading.Event()

    def interrupt_once_silent():
        if relay.quiet.wait(30) and running.is_set():
            time.sleep(0.1)
            os.kill(os.getpid(), sig)

    before = signal.signal(sig, lambda *_: None)  # one that came late is lost, not pytest's
    configure_app(app, load_settings(env))
    try:
        threading.Thread(target=interrupt_once_silent, daemon=True).start()
        running.set()
        t0 = time.monotonic()
        res = CliRunner().invoke(cli, [command[0], str(shot), "--model", "interp", *command[1:]])
        took = time.monotonic() - t0
        running.clear()
        assert res.exit_code == 130 and res.stdout == "", res.output
        (line,) = res.stderr.splitlines()
        assert line.startswith("tween: interrupted: cancelled the 1 job(s) it had sent ("), line
        job = line.rsplit("(", 1)[1].rstrip(")")
        assert jobs.state(job).state == "CANCELLED"  # its record is there, and its cancel
        assert took < 5  # reply_timeout is 8 s
    finally:
        relay.close()
        configure_app(app, old)
        signal.signal(sig, before)


def test_a_fill_whose_broker_goes_silent_while_it_waits_names_its_job(redis_farm):
    """The job sent and acknowledged, then no reply to the wait's reads: Celery's Redis
    client waited 120 s a read. Now one line within reply_timeout, naming the job."""
    r, url, took, _ = _through_relay(redis_farm, "fill", quiet_at=b"tween.validate", answered=True)
    assert r.returncode == 2 and r.stdout == "", r.stderr[-2000:]
    errors = [ln for ln in _lines(r) if ln.startswith("tween: error:")]
    job = _lines(r)[0].split()[2]  # "tween: job ID submitted (...)"
    assert errors == [
        f"tween: error: lost the broker while waiting for job(s) {job}, which may still run on the farm: "
        f"`tween status {job}` once the broker is back, `tween cancel {job}` to stop it; broker {url}: "
        "stopped answering (no reply within reply_timeout, 1 s: a stopped, wedged or overloaded server?) "
        "(the URL comes from TWEEN_BROKER_URL or the farm config)"
    ], r.stderr[-2000:]
    assert took < 20


def test_a_slow_broker_that_answers_within_reply_timeout_takes_a_submit(redis_farm):
    """Every reply held 0.1 s, reply_timeout 1 s: the timeout bounds each reply, not the
    command, so a slow broker still works."""
    r, *_ = _through_relay(redis_farm, "submit", delay=0.1)
    assert r.returncode == 0, r.stderr[-2000:]
    assert len(r.stdout.split()) == 1 and _lines(r) == []


def test_a_worker_keeps_celery_retry_policies_a_client_does_not():
    """A client gives up at the first failed publish or result write (each retry waited
    reply_timeout again); a worker still rides out a restart with Celery's retries."""
    from celery import Celery
    from celery.app.defaults import DEFAULTS

    import workers.app as wa
    from workers.settings import load_settings

    s = load_settings({"TWEEN_FARM_CONFIG": os.devnull, "TWEEN_BROKER_URL": "redis://127.0.0.1:1/0"})
    client = wa.configure(Celery("tween-client", set_as_current=False), s)
    assert client.conf.task_publish_retry_policy == {"max_retries": 0}
    assert client.backend.retry_policy["max_retries"] == 0
    assert client.conf.broker_transport_options["socket_timeout"] == s.reply_timeout == 10
    worker = wa.for_worker(wa.configure(Celery("tween-worker", set_as_current=False), s))
    assert worker.conf.task_publish_retry_policy == DEFAULTS["task_publish_retry_policy"]
    assert worker.backend.retry_policy["max_retries"] == 20
    assert worker.conf.result_backend_transport_options["global_keyprefix"] == s.key_prefix


def _database_farm(tmp_path, backend: str = ""):
    """A client's fill app whose result backend is a database: an SQLite file under
    ``tmp_path``, or (settings only: no PostgreSQL driver needs to be installed) ``backend``."""
    from dataclasses import replace

    from celery import Celery

    import workers.app as wa
    from workers.settings import load_settings

    env = {"TWEEN_FARM_CONFIG": os.devnull, "TWEEN_BROKER_URL": "redis://127.0.0.1:1/0",
           "TWEEN_RESULT_BACKEND": f"db+sqlite:///{tmp_path / 'results.sqlite'}"}  # fmt: skip
    s = load_settings(env)
    return wa.configure(
        Celery("tween-db", set_as_current=False), replace(s, result_backend=backend) if backend else s
    )


def test_a_postgresql_backend_waits_on_its_server_at_most_reply_timeout(tmp_path):
    """Redis and RabbitMQ had their socket timeouts; a PostgreSQL result backend none: a
    server gone silent held every farm command for ever. libpq's bounds (psycopg, psycopg2),
    pg8000's socket timeout; what the URL sets itself stands."""
    t = 10
    opts = _database_farm(tmp_path, "db+postgresql://farm:pw@db.studio/farm").conf.database_engine_options
    assert opts == {"connect_args": {"connect_timeout": t, "keepalives": 1, "keepalives_idle": t,
                                     "keepalives_interval": 1, "keepalives_count": 3, "tcp_user_timeout": t * 1000,
                                     "options": f"-c statement_timeout={t * 1000}"}}  # fmt: skip
    url = "db+postgresql+psycopg2://farm@db.studio/farm?connect_timeout=3&options=-c%20search_path%3Dtween"
    args = _database_farm(tmp_path, url).conf.database_engine_options["connect_args"]
    assert (
        "connect_timeout" not in args
        and args["options"] == f"-c statement_timeout={t * 1000} -c search_path=tween"
    )
    pg8000 = _database_farm(tmp_path, "db+postgresql+pg8000://farm@db.studio/farm")
    assert pg8000.conf.database_engine_options == {"connect_args": {"timeout": t}}
    assert _database_farm(tmp_path, "db+mysql://farm@db.studio/farm").conf.database_engine_options == {}


class _DriverError(Exception):
    """A PostgreSQL driver's error, as psycopg2 raises it."""

    def __init__(self, text: str, pgcode: str | None = None):
        super().__init__(text)
        self.pgcode = pgcode


def _raised_inside_sqlalchemy(error: BaseException):
    """Raises ``error`` from code of a module named sqlalchemy.pool (as pg8000's socket
    timeout comes through SQLAlchemy's connect)."""
    exec("def connect(e):\n    raise e\n", scope := {"__name__": "sqlalchemy.pool.base"})
    scope["connect"](error)


@pytest.mark.parametrize(
    ("error", "why"),
    [
        (_DriverError("canceling statement due to statement timeout", "57014"), "stopped answering"),
        (_DriverError('connection to server at "db.studio" failed: timeout expired'), "stopped answering"),
        (_DriverError("could not receive data from server: Connection timed out"), "stopped answering"),
        (TimeoutError("timed out"), "stopped answering"),
        (_DriverError('FATAL: password authentication failed for user "farm"'), "cannot connect"),
    ],
    ids=["statement_timeout", "connect_timeout", "tcp_user_timeout", "pg8000_timeout", "refused"],
)
def test_a_postgresql_backend_lost_mid_command_is_one_line(tmp_path, error, why):
    """Its errors (Celery's own, raised from SQLAlchemy's, raised from the driver's) were an
    internal error; now the line the other backends give, naming the jobs that may still run."""
    import sqlalchemy.exc
    from celery.exceptions import BackendGetMetaError

    import workers.app as wa

    app = _database_farm(tmp_path, "db+postgresql://farm:secret@db.studio/farm")
    with pytest.raises(wa.FarmConnectionError) as e, wa.farm_errors(app, ["J1"]):
        try:
            if isinstance(error, OSError):  # pg8000's, raised as it is
                _raised_inside_sqlalchemy(error)
            raise sqlalchemy.exc.OperationalError("SELECT 1", {}, error)
        except Exception:
            raise BackendGetMetaError("failed to get meta", task_id="J1") from None
    head = ("lost the result backend while waiting for job(s) J1, which may still run on the farm: `tween status "
            "J1` once the result backend is back, `tween cancel J1` to stop it; result backend "
            "db+postgresql://farm:***@db.studio/farm: ")  # fmt: skip
    tail = "(the URL comes from TWEEN_RESULT_BACKEND or the farm config)"
    if why == "stopped answering":
        assert str(e.value) == head + ("stopped answering (no reply within reply_timeout, 10 s: a stopped, wedged "
                                       "or overloaded server?) " + tail)  # fmt: skip
    else:
        assert str(e.value) == head + f"cannot connect: {' '.join(str(error).split())} {tail}"


def test_a_database_backend_a_client_cannot_use_is_one_line_at_once(tmp_path):
    """Its SQLite file made unusable after the client's first read: Celery retried 3 times,
    then an internal error. A client does not retry (each retry waited its connect timeout
    again); a worker keeps Celery's retries."""
    import workers.app as wa
    from workers.errors import FarmConnectionError

    app = _database_farm(tmp_path)
    assert app.backend.max_retries == 0
    app.backend.get_task_meta("j0")  # its tables made
    (tmp_path / "results.sqlite").unlink()
    (tmp_path / "results.sqlite").mkdir()  # not a database file any more
    t0 = time.monotonic()
    with pytest.raises(FarmConnectionError) as e, wa.farm_errors(app):
        app.backend.get_task_meta("j1")
    assert time.monotonic() - t0 < 1
    assert str(e.value) == (f"result backend db+sqlite:///{tmp_path / 'results.sqlite'}: cannot connect: unable "
                            "to open database file (the URL comes from TWEEN_RESULT_BACKEND or the farm config)")  # fmt: skip
    (tmp_path / "w").mkdir()
    worker = wa.for_worker(_database_farm(tmp_path / "w"))
    assert worker.backend.max_retries == 3  # Celery's, for a database backend


def _redis_server(port: int, folder) -> subprocess.Popen:
    exe = shutil.which("redis-server")
    if exe is None:
        pytest.skip("no redis-server")
    cmd = [exe, "--port", str(port), "--bind", "127.0.0.1", "--save", "", "--dir", str(folder)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    for _ in range(100):
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return proc
        except OSError:
            time.sleep(0.05)
    proc.kill()
    pytest.skip("redis-server did not start")


def test_a_fill_that_loses_its_broker_names_its_job(tmp_path):
    """A private Redis stopped while `tween fill` waits on its queued job (no worker)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    shot = tmp_path / "sh010.usda"
    shutil.copyfile(REPO / "examples" / "sh010_walk.usda", shot)
    proc = _redis_server(port, tmp_path)
    env = {k: v for k, v in os.environ.items() if not k.startswith("TWEEN_")}
    env.update(TWEEN_FARM_CONFIG=os.devnull, TWEEN_BROKER_URL=f"redis://127.0.0.1:{port}/0",
               TWEEN_SHOT_ROOTS=str(tmp_path), TWEEN_QUEUE=f"q-{uuid.uuid4().hex[:8]}")  # fmt: skip
    cmd = [sys.executable, "-m", "pipeline.cli", "fill", str(shot), "--model", "interp"]
    fill = subprocess.Popen(
        cmd, env=env, cwd=REPO, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True
    )
    try:
        first = fill.stderr.readline()  # "tween: job ID submitted (...)"
        assert "submitted" in first, first
        job = first.split()[2]
    finally:
        proc.kill()
        proc.wait()
    err = first + fill.stderr.read()
    assert fill.wait(timeout=60) == 2, err
    last = [ln for ln in err.replace("\r", "\n").splitlines() if ln.strip()][-1]
    assert last.startswith(
        f"tween: error: lost the broker while waiting for job(s) {job}, which may still run"
    ), last
    assert f"`tween status {job}` once the broker is back, `tween cancel {job}` to stop it" in last


def test_limit_advice_names_no_config_file_that_is_not_one():
    from celery.exceptions import TimeLimitExceeded

    from workers.limits import failure_message
    from workers.settings import load_settings

    env = {"TWEEN_FARM_CONFIG": os.devnull}
    msg = failure_message(TimeLimitExceeded(50), "sh.usda", load_settings(env), env, stage="validate")
    assert msg.startswith("fill of sh.usda hit the farm's hard time limit (fill_time_limit = 50 s); ")
    assert "raise it with TWEEN_FILL_TIME_LIMIT" in msg and os.devnull not in msg


@pytest.mark.parametrize("silent_s", [60, 0])
def test_a_stage_killed_after_its_heartbeats_stopped_says_so(embedded_app, silent_s):
    """The validate stage's last heartbeat 60 s before it was killed at its hard limit: the
    worker lost the backend (the limit is not the cause); beats to the end: the limit is."""
    from celery.exceptions import TimeLimitExceeded

    from workers import control, jobs
    from workers.app import SUBMITTED

    job = uuid.uuid4().hex
    tid = f"{job}.validate"
    embedded_app.backend.store_result(job, {"shot": "/s/sh.usda", "takes": 1, "render": False}, SUBMITTED)
    beat = {
        "time": time.time() - silent_s,
        "ended": False,
        "interval": 2,
        "worker": "w",
        "pid": 1,
        "host": "h",
    }
    embedded_app.backend.store_result(control.beat_id(tid), beat, control.BEAT_STATE)
    embedded_app.backend.mark_as_failure(tid, TimeLimitExceeded(50))
    s = jobs.state(job)
    assert s.state == "FAILURE" and s.stage == "validate"
    if silent_s:
        assert s.error.startswith("validate of /s/sh.usda was stopped at its hard time limit, but its worker "
                                  "had written no heartbeat for the 60 s before: it lost the farm's result "
                                  "backend (or broker)"), s.error  # fmt: skip
    else:
        assert s.error.startswith("fill of /s/sh.usda hit the farm's hard time limit"), s.error


def test_embedded_publish_on_a_full_disk_is_one_error(tmp_path):
    """SQLite's own SQLITE_FULL (``PRAGMA max_page_count`` at the file's size: it cannot grow)
    while the embedded broker publishes: StoreFullError naming its folder, not kombu's retry
    on a closed channel (AttributeError)."""
    from kombu import Connection
    from sqlalchemy import event
    from sqlalchemy.engine import Engine

    from workers import sqlite_transport  # registers the embedded transport

    url = f"tweensqla+sqlite:///{tmp_path / 'broker.sqlite'}"
    with Connection(url) as conn:
        conn.SimpleQueue("q").put({"n": 0})  # the tables and the queue exist

        def full(dbapi_conn, _):
            dbapi_conn.execute("PRAGMA max_page_count = 1")  # clamped to the current size

        event.listen(Engine, "connect", full)
        try:
            for engine, _ in sqlite_transport.kombu_sqla.Channel._engines.values():
                engine.dispose()  # new connections, which get the pragma
            with pytest.raises(Exception) as e, Connection(url) as c2:
                c2.SimpleQueue("q").put({"n": "x" * 200_000})
        finally:
            event.remove(Engine, "connect", full)
    assert type(e.value).__name__ == "StoreFullError", repr(e.value)
    assert str(e.value).startswith(f"{tmp_path}: the disk is full")


def test_embedded_fill_on_a_full_disk_is_one_line(tmp_path):
    """Every SQLite file of the run (the client's and its worker's) unable to grow, as on a
    full disk: `tween fill` says so in one line naming the cache folder, exit status 2."""
    hooks = tmp_path / "hooks"
    hooks.mkdir()
    (hooks / "sitecustomize.py").write_text(
        "from sqlalchemy import event\nfrom sqlalchemy.engine import Engine\n\n\n"
        "@event.listens_for(Engine, 'connect')\ndef _full(dbapi_conn, _):\n"
        "    dbapi_conn.execute('PRAGMA max_page_count = 1')\n"
    )
    shot = tmp_path / "sh010.usda"
    shutil.copyfile(REPO / "examples" / "sh010_walk.usda", shot)
    cache = tmp_path / "cache"
    env = {"TWEEN_CACHE": str(cache), "PYTHONPATH": os.pathsep.join([str(hooks), str(REPO)])}
    r = _tween("fill", shot, "--model", "interp", "--no-progress", env=env, timeout=120)
    assert r.returncode == 2, r.stderr[-3000:]
    assert _lines(r) == [
        f"tween: error: {cache / 'farm'}: the disk is full (the embedded farm's broker and result store "
        "live in this cache folder, TWEEN_CACHE); free space there or set TWEEN_CACHE to another folder"
    ]


def _embedded_fill(
    tmp_path, fsize: int | None = None, hook: str = ""
) -> tuple[subprocess.CompletedProcess, float]:
    """`tween fill` on the embedded farm under ``tmp_path``: with ``fsize`` every process of
    the run (client, worker, pool) may write files of at most that many bytes (a full disk,
    as tests/test_full_disk.py makes one); ``hook`` is a sitecustomize for every process."""
    import resource
    import signal

    shot = tmp_path / "shots" / "sh010.usda"
    shot.parent.mkdir()
    shutil.copyfile(REPO / "examples" / "sh010_walk.usda", shot)
    env = {k: v for k, v in os.environ.items() if not k.startswith("TWEEN_")}
    env.update(TWEEN_FARM_CONFIG=os.devnull, TWEEN_CACHE=str(tmp_path / "cache"))
    if "TWEEN_DATA" in os.environ:
        env["TWEEN_DATA"] = os.environ["TWEEN_DATA"]
    if hook:
        (tmp_path / "hooks").mkdir()
        (tmp_path / "hooks" / "sitecustomize.py").write_text(hook)
        env["PYTHONPATH"] = os.pathsep.join([str(tmp_path / "hooks"), str(REPO)])

    def small_disk():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

    cmd = [sys.executable, "-m", "pipeline.cli", "fill", str(shot), "--model", "interp", "--no-progress"]
    t0 = time.monotonic()
    r = subprocess.run(cmd, env=env, cwd=REPO, capture_output=True, text=True, timeout=60,
                       preexec_fn=small_disk if fsize else None)  # fmt: skip
    assert sorted(p.name for p in shot.parent.iterdir()) == ["sh010.usda"]  # nothing of the job left
    return r, time.monotonic() - t0


def _store_full_line(tmp_path) -> list[str]:
    return [
        f"tween: error: {tmp_path / 'cache' / 'farm'}: the disk is full (the embedded farm's broker and result "
        "store live in this cache folder, TWEEN_CACHE); free space there or set TWEEN_CACHE to another folder"
    ]


def test_embedded_cache_disk_filling_mid_job_is_one_line(tmp_path):
    """Files of at most 44 kB: the job starts (the shot's own files are smaller), then the
    worker's broker file cannot grow. It was SQLite's two-line "disk I/O error", or the worker
    retried the broker for 40 s and "exited with code 0"; now one line, in seconds."""
    r, took = _embedded_fill(tmp_path, fsize=44_000)
    assert r.returncode == 2 and r.stdout == "", r.stderr[-3000:]
    assert _lines(r) == _store_full_line(tmp_path)
    assert took < 30


def test_an_embedded_worker_that_cannot_store_its_results_ends_the_fill(tmp_path):
    """The worker's result store cannot grow (its broker can): Celery logged each stage's
    result it could not store and ran on, and `tween fill` waited for ever."""
    hook = (
        "import sys\n"
        "if 'worker' in sys.argv:\n"
        "    from sqlalchemy import event\n"
        "    from sqlalchemy.engine import Engine\n\n"
        "    @event.listens_for(Engine, 'connect')\n"
        "    def _full(dbapi_conn, _):\n"
        "        if any(str(r[2]).endswith('results.sqlite') for r in dbapi_conn.execute('PRAGMA database_list')):\n"
        "            dbapi_conn.execute('PRAGMA max_page_count = 1')\n"
    )
    r, took = _embedded_fill(tmp_path, hook=hook)
    assert r.returncode == 2 and r.stdout == "", r.stderr[-3000:]
    assert _lines(r) == _store_full_line(tmp_path)
    assert took < 30
