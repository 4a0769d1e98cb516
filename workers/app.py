"""The Celery apps of the farm, with all their configuration in this one place.

``app`` runs the per-shot fill job (validate → takes → layer → review) on the fill queue.
``train_app`` runs long jobs (model training) on their own queue. With Redis the visibility
timeout is a property of the connection, not of a queue, so the training app keeps its own
key prefix (its own ``unacked`` set) and a visibility timeout of hours, while the fill app's
stays about a minute: a dead host's fill is taken over quickly whatever training runs.
``rig_app`` does the same for per-rig model training (``tween train-rig``): its own queue,
key prefix (``<prefix>rig:``), time limits and visibility timeout.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from contextlib import contextmanager
from urllib.parse import parse_qs, urlsplit

from celery import Celery

import workers.sqlite_transport  # noqa: F401  (registers the embedded transport alias)
from workers import backends, security
from workers.errors import FarmConnectionError, raised_from
from workers.settings import FarmConfigError, FarmSettings, load_settings, redact_url, url_passwords

#: Celery's own states plus the one the job record is stored under.
SUBMITTED = "SUBMITTED"


def _transport_options(s: FarmSettings, visibility_timeout: int, prefix: str) -> dict:
    if s.is_redis:
        return {
            "visibility_timeout": visibility_timeout,
            # kombu 5.7 sweeps unacked messages every interval × throttle seconds (default
            # 10 × 10); throttle 1 makes the interval alone decide the takeover delay.
            "unacked_restore_interval": s.restore_interval,
            "unacked_restore_throttle": 1,
            "global_keyprefix": prefix,
            # kombu waits for ever for a reply by default: a Redis that stops answering after
            # the start-up check hung `tween submit`'s publish for good.
            "socket_timeout": s.reply_timeout,
            "socket_connect_timeout": s.reply_timeout,
        }
    if s.broker_url.startswith(("amqp://", "amqps://", "pyamqp://")):
        # The same for py-amqp's socket (a publish waits for its confirm); the worker's event
        # loop reads only what has arrived, so an idle worker never times out.
        return {"confirm_publish": True, "read_timeout": s.reply_timeout, "write_timeout": s.reply_timeout}
    return {}


#: A farm client does not retry a publish or a result write (Celery: 3 and 20 times): the
#: start-up check has just reached the server, so a failure now is a server that went down
#: or silent, and each retry, its reconnection included, waited ``reply_timeout`` again (a
#: silent Redis held `tween submit` 30 s with one retry). A worker keeps Celery's policies
#: (:func:`for_worker`): it rides out a broker or backend restart.
CLIENT_PUBLISH_RETRY = {"max_retries": 0}
CLIENT_BACKEND_RETRY = {"max_retries": 0}


def _backend_options(s: FarmSettings, prefix: str) -> dict:
    if s.result_backend.startswith(("redis://", "rediss://")):
        return {"global_keyprefix": prefix, "retry_policy": dict(CLIENT_BACKEND_RETRY)}
    return {}


def _reply_limits(s: FarmSettings) -> dict:
    """Celery's settings that bound a client's wait on the broker and the Redis result
    backend (the transport options bound the broker's socket): no publish retried, and
    the backend's reply wait (Celery's: 120 s, then 20 retries); no database backend's
    operation retried either (Celery's: 3 times, each waiting its own connect timeout), but
    on the embedded farm's own SQLite files (Celery's 3 kept)."""
    return {
        "task_publish_retry_policy": dict(CLIENT_PUBLISH_RETRY),
        "redis_socket_timeout": s.reply_timeout,
        "redis_socket_connect_timeout": s.reply_timeout,
        "result_backend_max_retries": DATABASE_RETRIES if s.embedded else 0,
    }


#: Celery's retries of a database backend's operation, where none are set.
DATABASE_RETRIES = 3


#: The PostgreSQL drivers that take libpq's connection parameters (SQLAlchemy's default first).
LIBPQ_DRIVERS = ("", "psycopg2", "psycopg", "psycopg2cffi")


def _database_options(s: FarmSettings) -> dict:
    """Celery's ``database_engine_options``: the embedded farm's SQLite busy timeout; for a
    PostgreSQL result backend, bounds of reply_timeout on its waits for the server, which
    were unbounded (Redis and AMQP have their socket timeouts). With libpq: the connection
    (connect_timeout: a client connects for each operation), a host or network gone (TCP
    keepalives, tcp_user_timeout) and a statement the server does not finish
    (statement_timeout); with pg8000, its socket timeout. What the URL sets stands.

    A server that stops answering while its host still acknowledges the traffic (a stopped
    postgres process) in the middle of a statement is bounded by pg8000 only: libpq has no
    read timeout, and its keepalives are answered."""
    if s.embedded:
        return {"connect_args": {"timeout": 30}}
    url = s.result_backend.removeprefix("db+").removeprefix("database+")
    dialect, _, driver = url.split("://", 1)[0].partition("+")
    if dialect != "postgresql" or driver not in (*LIBPQ_DRIVERS, "pg8000"):
        return {}
    t = s.reply_timeout
    if driver == "pg8000":
        args: dict = {"timeout": t}
    else:
        args = {"connect_timeout": t, "keepalives": 1, "keepalives_idle": t, "keepalives_interval": 1,
                "keepalives_count": 3, "tcp_user_timeout": t * 1000, "options": f"-c statement_timeout={t * 1000}"}  # fmt: skip
    given = parse_qs(urlsplit(url).query)
    if "options" in given and "options" in args:  # its own options after (a later -c wins)
        args["options"] += " " + given["options"][-1]
    return {"connect_args": {k: v for k, v in args.items() if k == "options" or k not in given}}


def for_worker(celery_app: Celery) -> Celery:
    """Gives the app a worker's retry policies, Celery's defaults, before it starts: a worker
    waits out a broker or backend restart, where a client gives up within seconds."""
    from celery.app.defaults import DEFAULTS

    opts = dict(celery_app.conf.result_backend_transport_options or {})
    opts.pop("retry_policy", None)
    celery_app.conf.update(
        task_publish_retry_policy=dict(DEFAULTS["task_publish_retry_policy"]),
        result_backend_transport_options=opts,
    )
    celery_app.conf.pop("result_backend_max_retries", None)  # unset: each backend's own default
    return celery_app


def configure(app: Celery, s: FarmSettings, *, train: bool = False, rig: bool = False) -> Celery:
    """Applies the farm settings to ``app`` (the fill app, the training app, or with
    ``rig`` the per-rig training app)."""
    if rig:
        prefix, vt, hard, queue = (
            s.key_prefix + "rig:",
            s.train_rig_visibility_timeout,
            s.train_rig_time_limit,
            s.train_rig_queue,
        )
    elif train:
        prefix, vt, hard, queue = (
            s.key_prefix + "train:",
            s.train_visibility_timeout,
            s.train_time_limit,
            s.train_queue,
        )
    else:
        prefix, vt, hard, queue = s.key_prefix, s.visibility_timeout, s.fill_time_limit, s.queue
    soft = int(hard * 0.95) if (train or rig) else s.fill_soft_time_limit
    app.conf.update(
        broker_url=s.broker_url,
        result_backend=s.result_backend,
        broker_transport_options=_transport_options(s, vt, prefix),
        result_backend_transport_options=_backend_options(s, prefix),
        broker_connection_retry_on_startup=True,
        **_reply_limits(s),
        # JSON only: a message can never execute code when it is decoded.
        task_serializer="json",
        result_serializer="json",
        accept_content=["json"],
        result_accept_content=["json"],
        # Ack after the task returns, and requeue if the pool child dies: nothing is lost.
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        worker_prefetch_multiplier=1,
        task_track_started=True,
        task_time_limit=hard,
        task_soft_time_limit=soft,
        task_default_queue=queue,
        task_create_missing_queues=True,
        result_expires=7 * 24 * 3600,
        result_extended=True,
        # The database backend has no native chord counter: poll the header quickly.
        result_chord_retry_interval=0.2,
        # Recycle processes now and then: USD, ORT and GL hold caches that only grow.
        worker_max_tasks_per_child=200,
        worker_send_task_events=False,
        worker_hijack_root_logger=False,
        database_engine_options=_database_options(s),
        database_create_tables_at_setup=True,
        # The SQLite broker has no broadcast; remote control only makes sense on a real farm.
        worker_enable_remote_control=not s.embedded,
    )
    # TLS to the broker and backend, signed task messages: workers/security.py.
    security.apply(app, s)
    app.conf.tween = s
    return app


def _settings() -> tuple[FarmSettings, FarmConfigError | None]:
    """The farm settings, and the configuration's error when it has one. A bad setting must
    not break the commands that need no farm (``tween fill-local``, ``convert``, …: this
    module is imported when the CLI registers its commands), so the apps are then made with
    the defaults and every farm command says the error in one line (:func:`check_farm`)."""
    try:
        return load_settings(), None
    except FarmConfigError as e:
        keep = {k: v for k, v in os.environ.items() if k == "TWEEN_CACHE"}
        return load_settings({**keep, "TWEEN_FARM_CONFIG": os.devnull}), e


settings, SETTINGS_ERROR = _settings()
app = configure(Celery("tween", include=["workers.tasks"]), settings)
train_app = configure(Celery("tween-train", include=["workers.train_tasks"]), settings, train=True)
rig_app = configure(Celery("tween-rig", include=["workers.rig_tasks"]), settings, rig=True)


#: How long the CLI tries a broker or result backend before it gives up (seconds, about).
CONNECT_TIMEOUT = 3.0


def _why(e: BaseException, url: str) -> str:
    """An exception's text on one line, with the URL's passwords hidden."""
    text = " ".join(str(e).split()) or type(e).__name__
    text = text.replace(url, redact_url(url))
    for pw in url_passwords(url):
        if len(pw) >= 4:
            text = text.replace(pw, "***")
    return text


def connection_error(what: str, url: str, e: BaseException, env: str = "") -> FarmConnectionError:
    """The one-line error for an unreachable ``what`` ("broker" or "result backend")."""
    env = env or ("TWEEN_BROKER_URL" if what == "broker" else "TWEEN_RESULT_BACKEND")
    return FarmConnectionError(
        f"{what} {redact_url(url)}: cannot connect: {_why(e, url)} (the URL comes from {env} or "
        "the farm config)"
    )


#: How long a farm command waits for the broker or result backend to answer its first
#: request, connection included: a server that accepts the connection and never replies (a
#: stopped or wedged Redis) hung every farm command, the client libraries waiting forever.
ANSWER_TIMEOUT = 8.0


def _answered(what: str, url: str, check, env: str = "", within: float | None = None) -> None:
    """Runs ``check`` in a daemon thread and waits at most ``within`` (ANSWER_TIMEOUT) s for
    it: its own error, or FarmConnectionError naming the URL when it did not answer. A thread,
    because no socket timeout bounds them all (redis-py retries a timeout itself, TLS and
    AMQP handshakes have their own); a hung one is left behind."""
    within = ANSWER_TIMEOUT if within is None else within
    out: list[BaseException | None] = []

    def run() -> None:
        try:
            check()
            out.append(None)
        except BaseException as e:  # handed to the waiting thread
            out.append(e)

    t = threading.Thread(target=run, name=f"tween-{what.replace(' ', '-')}-check", daemon=True)
    t.start()
    t.join(within)
    if not out:
        env = env or ("TWEEN_BROKER_URL" if what == "broker" else "TWEEN_RESULT_BACKEND")
        raise FarmConnectionError(
            f"{what} {redact_url(url)}: did not answer within {within:g} s (it accepts the connection "
            f"but sends nothing back: a stopped, wedged or overloaded server?) (the URL comes from {env} "
            "or the farm config)"
        )
    if out[0] is not None:
        raise out[0]


def check_broker(celery_app: Celery, timeout: float = CONNECT_TIMEOUT, within: float | None = None) -> None:
    """Connects to ``celery_app``'s broker once, with a short bounded retry; raises
    FarmConnectionError naming the URL (password hidden) when it cannot, or when it does not
    answer within ``within`` s (:func:`_answered`)."""
    url = celery_app.conf.broker_url

    def check() -> None:
        try:
            conn = celery_app.connection_for_write(connect_timeout=timeout)
            try:
                conn.ensure_connection(max_retries=2, interval_start=0.2, interval_step=0.5,
                                       interval_max=1.0, timeout=timeout)  # fmt: skip
            finally:
                conn.release()
        except Exception as e:  # any failure to connect (refused, DNS, auth, unknown transport) is one line
            raise connection_error("broker", url, e) from None

    _answered("broker", url, check, within=within)


def check_backend(celery_app: Celery, timeout: float = CONNECT_TIMEOUT, within: float | None = None) -> None:
    """Pings a Redis result backend (with a short bounded retry); of another backend, checks
    that its database can be reached (workers/backends.py: an SQLite file's folder, a
    server's port) without connecting to it (a database backend would create its tables).
    Either answers within ``within`` s or is one line (:func:`_answered`)."""
    url = celery_app.conf.result_backend
    if not str(url).startswith(("redis://", "rediss://")):
        try:
            backends.reach(str(url), timeout)
        except OSError as e:
            raise connection_error("result backend", url, e) from None
        return
    same = url == celery_app.conf.broker_url  # Redis: the backend is the broker by default
    what, env = ("broker", "TWEEN_BROKER_URL") if same else ("result backend", "")

    def check() -> None:
        deadline = time.monotonic() + timeout / 2  # redis-py retries each ping a few times itself
        while True:
            try:
                celery_app.backend.client.ping()  # (the thread's own backend: Celery's is per thread)
                return
            except Exception as e:
                if time.monotonic() + 0.3 > deadline:
                    raise connection_error(what, url, e, env) from None
                time.sleep(0.3)

    _answered(what, url, check, env, within)


def check_farm(celery_app: Celery, *, broker: bool = True, backend: bool = True) -> None:
    """Fails fast, in one line, when the farm's configuration is wrong or the farm the CLI
    talks to cannot be reached."""
    if SETTINGS_ERROR is not None:
        raise SETTINGS_ERROR
    if celery_app.conf.tween.embedded:
        check_embedded_stores(celery_app)
        return
    if broker:
        check_broker(celery_app)
    if backend:
        check_backend(celery_app)


#: The first bytes of every SQLite database file.
SQLITE_HEADER = b"SQLite format 3\x00"


def check_embedded_stores(celery_app: Celery) -> None:
    """The embedded farm's SQLite broker and result store, where they exist, are SQLite
    databases: a damaged one (truncated, overwritten) was an internal DatabaseError."""
    for what, url in (
        ("broker", celery_app.conf.broker_url),
        ("result store", celery_app.conf.result_backend),
    ):
        path = str(url).split(":///", 1)[-1]
        try:
            with open(path, "rb") as f:
                head = f.read(len(SQLITE_HEADER))
        except FileNotFoundError:
            continue  # made on first use
        except OSError as e:
            raise FarmConfigError(
                f"{path}: cannot read the embedded farm's {what}: {e.strerror or e}"
            ) from None
        if head and head != SQLITE_HEADER:
            raise FarmConfigError(
                f"{path}: the embedded farm's {what} is damaged (not an SQLite database); remove it "
                "(it holds only earlier embedded runs' queues and records)"
            )


#: SQLSTATE query_canceled: PostgreSQL ended a statement at its statement_timeout.
PG_QUERY_CANCELED = "57014"


def _no_reply(e: BaseException | None) -> bool:
    """Whether ``e``, or an error it was raised from (kombu wraps the client's), is a reply
    that did not come within the socket timeout: redis-py's TimeoutError or a socket's; or
    a PostgreSQL backend's bound (:func:`_database_options`): libpq's connect_timeout ("timeout
    expired"), its connection timed out, or the statement_timeout."""
    return any(
        isinstance(x, TimeoutError)
        or (type(x).__name__ == "TimeoutError" and "redis" in type(x).__module__)
        or PG_QUERY_CANCELED in (getattr(x, "pgcode", None), getattr(x, "sqlstate", None))
        or any(words in str(x) for words in ("timeout expired", "Connection timed out"))
        for x in raised_from(e)
    )


def _raised_in(e: BaseException, modules: tuple[str, ...]) -> bool:
    """Whether ``e`` was raised from inside one of ``modules`` (or their submodules)."""
    tb = e.__traceback__
    while tb is not None:
        if tb.tb_frame.f_globals.get("__name__", "").startswith(modules):
            return True
        tb = tb.tb_next
    return False


def _database_error(celery_app: Celery, e: BaseException) -> BaseException | None:
    """The error of a farm's database result backend that could not be used that ``e`` is,
    or was raised from (Celery raises its own after its retries): SQLAlchemy's, or a socket's
    that the driver let through (pg8000's timeout as it connects). None for any other error,
    and on the embedded farm (its stores' errors are said elsewhere)."""
    exc = sys.modules.get("sqlalchemy.exc")  # not imported: no database was used
    url = str(celery_app.conf.result_backend)
    if exc is None or celery_app.conf.tween.embedded or not url.startswith(("db+", "database+")):
        return None
    for x in raised_from(e):
        if isinstance(x, (exc.OperationalError, exc.InterfaceError)):
            return getattr(x, "orig", None) or x  # the driver's own line, without SQLAlchemy's link
        if isinstance(x, OSError) and _raised_in(x, ("sqlalchemy.", "celery.backends.database")):
            return x
    return None


def _mid_command(what: str, url: str, e: BaseException, s: FarmSettings) -> FarmConnectionError:
    """The one-line error of a broker or result backend lost after the start-up check: one
    that stopped answering says so, with the setting that bounds the wait."""
    if not _no_reply(e):
        return connection_error(what, url, e)
    env = "TWEEN_BROKER_URL" if what == "broker" else "TWEEN_RESULT_BACKEND"
    return FarmConnectionError(
        f"{what} {redact_url(url)}: stopped answering (no reply within reply_timeout, {s.reply_timeout} s: a "
        f"stopped, wedged or overloaded server?) (the URL comes from {env} or the farm config)"
    )


def _lost(e: FarmConnectionError, what: str, job_ids: list[str]) -> FarmConnectionError:
    """The connection error of a command that had sent ``job_ids``: they may still run."""
    if not job_ids:
        return e
    ids = " ".join(job_ids)
    one = job_ids[0] if len(job_ids) == 1 else "ID"
    return FarmConnectionError(
        f"lost the {what} while waiting for job(s) {ids}, which may still run on the farm: "
        f"`tween status {one}` once the {what} is back, `tween cancel {one}` to stop it; {e}"
    )


@contextmanager
def farm_errors(celery_app: Celery, job_ids: list[str] | None = None):
    """Turns a broker or backend connection lost mid-command into the same one-line error;
    with ``job_ids`` (filled in as the command sends them) the line names those jobs, which
    the farm may still run (their client only lost sight of them)."""
    from kombu.exceptions import OperationalError

    try:
        from redis.exceptions import ConnectionError as RedisConnectionError
        from redis.exceptions import TimeoutError as RedisTimeoutError

        redis_errors: tuple = (RedisConnectionError, RedisTimeoutError)
    except ImportError:  # no Redis client installed
        redis_errors = ()
    try:
        yield
    except OperationalError as e:
        err = _mid_command("broker", celery_app.conf.broker_url, e, celery_app.conf.tween)
        raise _lost(err, "broker", job_ids or []) from None
    except redis_errors as e:
        url = celery_app.conf.result_backend
        what = "broker" if url == celery_app.conf.broker_url else "result backend"
        raise _lost(_mid_command(what, url, e, celery_app.conf.tween), what, job_ids or []) from None
    except Exception as e:
        db = _database_error(celery_app, e)
        if db is None:
            raise
        err = _mid_command("result backend", celery_app.conf.result_backend, db, celery_app.conf.tween)
        raise _lost(err, "result backend", job_ids or []) from None
