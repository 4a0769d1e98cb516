"""Is a result backend URL one this host can use? Checked where the settings are read
(:func:`problem`: a scheme Celery knows, whose module and driver import) and before a farm
command talks to it (:func:`reach`: the database answers within the broker check's timeout).

Celery itself finds out on first use: an unknown scheme was a ModuleNotFoundError, a missing
driver an ImproperlyConfigured, an SQLite file in a missing folder an OperationalError after
10 s of retries, and a worker that started on one logged hundreds of traceback lines and
exited 0. Celery is imported only when a backend is given (the embedded default needs none).
"""

from __future__ import annotations

import os
import socket
from urllib.parse import urlsplit

#: The ports a database backend listens on when its URL names none.
DEFAULT_PORTS = {
    "postgresql": 5432,
    "postgres": 5432,
    "mysql": 3306,
    "mariadb": 3306,
    "mssql": 1433,
    "oracle": 1521,
    "mongodb": 27017,
}
KNOWN = "redis://, rediss://, db+sqlite:///…, db+postgresql://…, …"


def _line(e: BaseException) -> str:
    return " ".join(str(e).split()) or type(e).__name__


def _database_problem(url: str) -> str | None:
    """Why the SQLAlchemy URL ``url`` (a ``db+`` backend's, without ``db+``) cannot be used
    here: it does not parse, or its dialect or driver is not installed."""
    from sqlalchemy.engine import make_url

    try:
        dialect = make_url(url).get_dialect()
        importer = getattr(dialect, "import_dbapi", None) or dialect.dbapi
        importer()
    except ImportError as e:
        return f"its database driver is not installed on this host ({e.name or _line(e)})"
    except Exception as e:  # ArgumentError: no URL; NoSuchModuleError: no such dialect
        return f"not a database URL SQLAlchemy knows ({_line(e).split(' (Background')[0]})"
    return None


def problem(url: str) -> str | None:
    """Why ``url`` is no result backend this host can use (None: it is): a scheme Celery does
    not know, a backend whose module or client library does not import. Reaches nothing."""
    from celery import Celery
    from celery.app.backends import by_url
    from celery.backends.database import DatabaseBackend
    from celery.backends.redis import RedisBackend
    from celery.backends.redis import redis as redis_client

    try:
        cls, plain = by_url(url)
    except Exception as e:  # an unknown scheme is looked up as a module: ModuleNotFoundError
        return f"not a result backend Celery knows ({_line(e)}); use {KNOWN}"
    if issubclass(cls, DatabaseBackend):
        return _database_problem(plain)
    if issubclass(cls, RedisBackend):  # its TLS options come with the farm's (workers/security.py)
        return None if redis_client is not None else "the redis Python package is not installed on this host"
    try:  # the other backends check their client library (and a file backend its folder) here
        cls(app=Celery("tween-check", set_as_current=False), url=plain)
    except Exception as e:
        return f"cannot be used on this host: {_line(e)}"
    return None


def _sqlite_path(url: str) -> str | None:
    """The file of a ``db+sqlite:///PATH`` URL (None: another database, or in memory)."""
    rest = url.removeprefix("db+").removeprefix("database+")
    if not rest.startswith("sqlite"):
        return None
    path = rest.split(":///", 1)[1] if ":///" in rest else ""
    path = path.split("?", 1)[0]
    return None if path in ("", ":memory:") else path


def reach(url: str, timeout: float) -> None:
    """Raises OSError unless the database of the backend ``url`` can be reached: an SQLite
    file's folder exists, a server accepts a TCP connection within ``timeout`` s. Writes
    nothing; a URL without a host (or a Redis one, pinged by the caller) is not checked."""
    path = _sqlite_path(url)
    if path is not None:
        folder = os.path.dirname(os.path.abspath(path))
        if not os.path.isdir(folder):
            raise FileNotFoundError(f"unable to open database file: no folder {folder}")
        return
    if url.startswith(("redis://", "rediss://")):
        return
    try:
        parts = urlsplit(url)
        host, port = parts.hostname, parts.port
    except ValueError:  # several hosts (mongodb://a,b/…): left to the backend
        return
    scheme = parts.scheme.removeprefix("db+").removeprefix("database+").split("+")[0]
    port = port or DEFAULT_PORTS.get(scheme)
    if not host or not port:
        return
    with socket.create_connection((host, port), timeout=timeout):
        pass
