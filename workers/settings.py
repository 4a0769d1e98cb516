"""Where the farm's settings come from: environment, then an optional TOML file, then defaults.

Every knob is ``TWEEN_<NAME>`` in the environment or ``<name>`` in the file named by
``$TWEEN_FARM_CONFIG`` (default ``~/.config/usd-tween/farm.toml``). With no broker configured
anywhere the farm runs *embedded*: kombu's SQLAlchemy transport and Celery's database result
backend on SQLite files under the cache folder, so nothing needs a server.
"""

from __future__ import annotations

import difflib
import os
import re
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from urllib.parse import unquote

from pipeline.data.cache_paths import cache_root
from pipeline.errors import TweenError
from workers import security


class FarmConfigError(TweenError):
    """The farm configuration is inconsistent."""


_USERINFO = re.compile(r"(?P<head>[A-Za-z][A-Za-z0-9+.-]*://[^:/@;?#]*):(?P<pw>[^@/;?#]*)@")
_QUERY_PW = re.compile(r"(?P<head>[?&](?:\w*password|passwd)=)(?P<pw>[^&;#]*)", re.I)


def redact_url(url: str) -> str:
    """``url`` with every password shown as ``***`` (``redis://:***@host:6379/0``,
    ``amqp://user:***@host//``, also ``?password=``), for messages and logs."""
    out = _USERINFO.sub(lambda m: f"{m['head']}:***@" if m["pw"] else m[0], str(url))
    return _QUERY_PW.sub(lambda m: f"{m['head']}***", out)


def url_passwords(url: str) -> list[str]:
    """The passwords in ``url`` (to scrub them out of error texts that might repeat them)."""

    found = [m["pw"] for m in _USERINFO.finditer(str(url))] + [m["pw"] for m in _QUERY_PW.finditer(str(url))]
    return sorted({v for p in found if p for v in (p, unquote(p))}, key=len, reverse=True)


def cache_dir(env=None) -> Path:
    """The cache root (:func:`pipeline.data.cache.cache_root`: one rule for every cache)."""
    return cache_root(env)


def config_file(env=None) -> Path:
    env = os.environ if env is None else env
    return Path(env.get("TWEEN_FARM_CONFIG", Path.home() / ".config" / "usd-tween" / "farm.toml"))


@dataclass(frozen=True)
class FarmSettings:
    """Resolved farm settings; see docs/farm.md for what each one trades off."""

    broker_url: str
    result_backend: str
    embedded: bool
    queue: str = "tween.fill"
    train_queue: str = "tween.train"
    key_prefix: str = "tween:"
    shot_roots: tuple[str, ...] = ()
    # Redis takeover: a dead host's task comes back after at most visibility_timeout plus one
    # restore sweep (restore_interval). The hard limit of every fill task must stay below
    # visibility_timeout, or a live task is handed out twice.
    visibility_timeout: int = 60
    restore_interval: int = 5
    fill_time_limit: int = 50
    fill_soft_time_limit: int = 40
    # The review render's own limits (workers/limits.py): these bases plus render_frame_ms
    # for every frame of every take, so a long shot gets the time it needs.
    render_time_limit: int = 120
    render_soft_time_limit: int = 100
    render_frame_ms: int = 250
    # How often a running stage says it is alive (and renews its Redis lease), and reads
    # whether its job was cancelled (workers/control.py).
    heartbeat_interval: int = 2
    train_time_limit: int = 12 * 3600
    train_visibility_timeout: int = 13 * 3600
    # Per-rig model training (`tween train-rig`, hours per clip on CPU): its own app, queue,
    # key prefix and visibility timeout, so it never blocks fills nor slows their takeover.
    train_rig_queue: str = "tween.train_rig"
    train_rig_time_limit: int = 16 * 3600
    train_rig_visibility_timeout: int = 17 * 3600
    # The motion library every fill job uses when it names none (`tween fill --library`).
    library: str = ""
    max_retries: int = 4
    retry_backoff_max: int = 30
    # A secured farm (workers/security.py): the CA that verifies the broker's and backend's
    # TLS certificates, and the key, certificate and trusted certificates of signed jobs.
    tls_ca_file: str = ""
    security_key: str = ""
    security_certificate: str = ""
    security_cert_store: str = ""
    security_digest: str = "sha256"
    extra: dict = field(default_factory=dict)

    def __repr__(self) -> str:  # the URLs may hold passwords: never in a log or a traceback
        vals = {f.name: getattr(self, f.name) for f in fields(self)}
        vals["broker_url"], vals["result_backend"] = (
            redact_url(self.broker_url),
            redact_url(self.result_backend),
        )
        return "FarmSettings(" + ", ".join(f"{k}={v!r}" for k, v in vals.items()) + ")"

    @property
    def is_redis(self) -> bool:
        return self.broker_url.startswith(("redis://", "rediss://", "redis+socket://"))


_INT_KEYS = (
    "visibility_timeout",
    "restore_interval",
    "fill_time_limit",
    "fill_soft_time_limit",
    "render_time_limit",
    "render_soft_time_limit",
    "render_frame_ms",
    "heartbeat_interval",
    "train_time_limit",
    "train_visibility_timeout",
    "train_rig_time_limit",
    "train_rig_visibility_timeout",
    "max_retries",
    "retry_backoff_max",
)
_STR_KEYS = (
    "broker_url",
    "result_backend",
    "queue",
    "train_queue",
    "train_rig_queue",
    "key_prefix",
    "library",
    "tls_ca_file",
    "security_key",
    "security_certificate",
    "security_cert_store",
    "security_digest",
)


def _nearest(key: str) -> str:
    near = difflib.get_close_matches(key, (*_INT_KEYS, *_STR_KEYS, "shot_roots"), n=1)
    return f" (did you mean {near[0]}?)" if near else ""


def _read_file(path: Path, named: bool = False) -> dict:
    """The settings in the TOML file ``path``; none when it does not exist, unless the user
    ``named`` it (``TWEEN_FARM_CONFIG``): a file named and missing is an error, not silence.
    ``/dev/null`` (no file) is no settings."""
    if not path.exists():
        if named:
            raise FarmConfigError(f"TWEEN_FARM_CONFIG={path}: no such farm config file")
        return {}
    if not path.is_file():
        return {}
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise FarmConfigError(f"{path}: cannot read farm config: {e}") from None
    unknown = sorted(set(data) - set(_INT_KEYS) - set(_STR_KEYS) - {"shot_roots"})
    if unknown:
        raise FarmConfigError(
            f"{path}: unknown farm setting(s): " + ", ".join(k + _nearest(k) for k in unknown)
        )
    for key in _STR_KEYS:
        if key in data and not isinstance(data[key], str):
            raise FarmConfigError(f"{path}: {key} must be a string, not {data[key]!r}")
    roots = data.get("shot_roots")
    if roots is not None and not (isinstance(roots, list) and all(isinstance(r, str) for r in roots)):
        raise FarmConfigError(f"{path}: shot_roots must be a list of folder paths, not {roots!r}")
    return data


def embedded_urls(folder: Path) -> tuple[str, str]:
    """Broker and result URLs of the server-less default, in ``folder``."""
    folder = folder.resolve()
    folder.mkdir(parents=True, exist_ok=True)
    return f"tweensqla+sqlite:///{folder / 'broker.sqlite'}", f"db+sqlite:///{folder / 'results.sqlite'}"


def _values(env, data: dict) -> tuple[dict, dict[str, str]]:
    """Each setting given, from ``env`` (first) or the config file's ``data``, typed and
    checked, and where each came from (for the error lines)."""
    vals: dict = {}
    origin: dict[str, str] = {}  # where each setting came from, for the error lines
    for key in _STR_KEYS + _INT_KEYS:
        raw = env.get(f"TWEEN_{key.upper()}")
        origin[key] = f"TWEEN_{key.upper()}"
        if raw is None or raw == "":
            raw = data.get(key)
            origin[key] = f"{config_file(env)}: {key}"
        if raw is None:
            continue
        if key in security.PATH_KEYS and raw:
            from_file = not origin[key].startswith("TWEEN_")
            raw = security.resolve_path(
                raw, os.path.dirname(os.path.abspath(config_file(env))) if from_file else None
            )
        if key in _INT_KEYS:
            where = (
                f"TWEEN_{key.upper()}" if env.get(f"TWEEN_{key.upper()}") else f"{config_file(env)}: {key}"
            )
            try:
                if isinstance(raw, bool) or isinstance(raw, float):
                    raise ValueError
                raw = int(raw)
            except (TypeError, ValueError):
                raise FarmConfigError(f"{where}: expected an integer, got {raw!r}") from None
            least = 0 if key == "max_retries" else 1
            if raw < least:
                raise FarmConfigError(f"{where}: must be {least} or more, got {raw}")
        vals[key] = raw
    roots = env.get("TWEEN_SHOT_ROOTS")
    if roots:
        vals["shot_roots"] = tuple(r for r in roots.split(os.pathsep) if r)
    elif data.get("shot_roots"):
        vals["shot_roots"] = tuple(data["shot_roots"])
    return vals, origin


def _broker_and_backend(vals: dict, env) -> tuple[str, str, bool]:
    """The broker and result backend URLs (taken out of ``vals``), and whether the farm is
    the embedded, server-less default (no broker given)."""
    broker = vals.pop("broker_url", None)
    backend = vals.pop("result_backend", None)
    embedded = broker is None
    if embedded:
        broker, default_backend = embedded_urls(cache_dir(env) / "farm")
        backend = backend or default_backend
    elif backend is None:
        if broker.startswith(("redis://", "rediss://")):
            backend = broker
        else:
            raise FarmConfigError(
                "TWEEN_RESULT_BACKEND is required with a non-Redis broker (chords need a real result "
                "backend: redis://... or db+postgresql://...)"
            )
    if backend.startswith("rpc://"):
        raise FarmConfigError("TWEEN_RESULT_BACKEND: rpc:// cannot run chords; use redis:// or db+...")
    return broker, backend, embedded


def _check_limits(s: FarmSettings) -> None:
    """Time limits, heartbeat and queues that agree with each other (and with Redis's
    visibility timeouts, on a Redis farm)."""
    if s.fill_soft_time_limit >= s.fill_time_limit:
        raise FarmConfigError("fill_soft_time_limit must be below fill_time_limit")
    if s.is_redis and s.fill_time_limit >= s.visibility_timeout:
        raise FarmConfigError(
            f"fill_time_limit ({s.fill_time_limit} s) must be below visibility_timeout "
            f"({s.visibility_timeout} s), or Redis hands a running task to a second worker"
        )
    if s.render_soft_time_limit >= s.render_time_limit:
        raise FarmConfigError(
            f"render_soft_time_limit ({s.render_soft_time_limit} s) must be below render_time_limit "
            f"({s.render_time_limit} s)"
        )
    if s.is_redis and 3 * s.heartbeat_interval > s.visibility_timeout:
        raise FarmConfigError(
            f"heartbeat_interval ({s.heartbeat_interval} s) must be at most a third of visibility_timeout "
            f"({s.visibility_timeout} s): a running stage renews its Redis lease at each heartbeat"
        )
    if s.is_redis and s.train_time_limit >= s.train_visibility_timeout:
        raise FarmConfigError("train_time_limit must be below train_visibility_timeout")
    if s.is_redis and s.train_rig_time_limit >= s.train_rig_visibility_timeout:
        raise FarmConfigError(
            f"train_rig_time_limit ({s.train_rig_time_limit} s) must be below train_rig_visibility_timeout "
            f"({s.train_rig_visibility_timeout} s), or Redis hands a running training to a second worker"
        )
    if len({s.queue, s.train_queue, s.train_rig_queue}) < 3:
        raise FarmConfigError("queue, train_queue and train_rig_queue must be three different queues")


def load_settings(env: dict | None = None) -> FarmSettings:
    """Resolves the settings from ``env`` (default ``os.environ``) and the config file."""
    env = os.environ if env is None else env
    data = _read_file(config_file(env), named=bool(env.get("TWEEN_FARM_CONFIG")))
    vals, origin = _values(env, data)
    broker, backend, embedded = _broker_and_backend(vals, env)
    s = FarmSettings(broker_url=broker, result_backend=backend, embedded=embedded, **vals)
    _check_limits(s)
    try:
        security.check(s, origin)
    except security.FarmConfigError as e:
        raise FarmConfigError(str(e)) from None
    return s
