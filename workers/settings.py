"""Where the farm's settings come from: environment, then an optional TOML file, then defaults.

Every knob is ``TWEEN_<NAME>`` in the environment or ``<name>`` in the file named by
``$TWEEN_FARM_CONFIG`` (default ``~/.config/usd-tween/farm.toml``). With no broker configured
anywhere the farm runs *embedded*: kombu's SQLAlchemy transport and Celery's database result
backend on SQLite files under the cache folder, so nothing needs a server.
"""

from __future__ import annotations

import difflib
import json
import os
import re
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from urllib.parse import unquote

from pipeline.data.cache_paths import cache_root
from pipeline.errors import TweenError
from workers import backends, security


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
    home = Path(env["HOME"]) if env.get("HOME") else Path.home()  # the HOME of ``env``
    return Path(env.get("TWEEN_FARM_CONFIG") or home / ".config" / "usd-tween" / "farm.toml")


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
    # How long a farm client waits for one reply of the broker or result backend once the
    # start-up check has passed (a server that goes silent mid-command hung it for good).
    reply_timeout: int = 10
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
    "reply_timeout",
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
_QUEUE_KEYS = ("queue", "train_queue", "train_rig_queue")
#: Path settings: made absolute, relative to the config file's folder when they come from it.
#: The only string settings whose empty value means "none" (their default); every other one
#: needs a value.
_PATH_KEYS = ("library", *security.PATH_KEYS)
#: The most a seconds-valued setting may be (7 days): far beyond any real limit, and within
#: what timers and waits can represent (a larger one overflows the worker's heartbeat wait).
MAX_SECONDS = 7 * 24 * 3600
#: The most of each integer setting (``max_retries`` has none).
_MOST = {
    **{k: MAX_SECONDS for k in _INT_KEYS if k not in ("render_frame_ms", "max_retries")},
    "render_frame_ms": 3_600_000,  # an hour a frame
}
#: The queues of the embedded farm (workers/embedded.py) start with this: private to one
#: `tween fill` client, whose jobs and files die with it.
EMBEDDED_QUEUE_PREFIX = "tween.embedded."
_URL_KEYS = ("broker_url", "result_backend")
_DIGITS = re.compile(r"-?[0-9]+")


def _nearest(key: str) -> str:
    near = difflib.get_close_matches(key, (*_INT_KEYS, *_STR_KEYS, "shot_roots"), n=1)
    return f" (did you mean {near[0]}?)" if near else ""


def _open_file(path: Path, named: bool) -> dict | None:
    """The parsed TOML file ``path``; None when there is none to read (missing and not
    ``named``, or ``/dev/null``). Anything else that is not a regular file is an error."""
    where = f"TWEEN_FARM_CONFIG={path}" if named else str(path)
    if str(path) == os.devnull:
        return None
    if not path.exists():
        if named:
            raise FarmConfigError(f"{where}: no such farm config file")
        return None
    if not path.is_file():
        if os.path.exists(os.devnull) and path.samefile(os.devnull):
            return None
        what = "a folder" if path.is_dir() else "not a regular file"
        raise FarmConfigError(
            f"{where}: {what}, not a farm config file (TWEEN_FARM_CONFIG={os.devnull}: no settings)"
        )
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except UnicodeDecodeError as e:
        raise FarmConfigError(
            f"{path}: cannot read farm config: not UTF-8 text (byte {e.object[e.start]:#04x} at offset {e.start})"
        ) from None
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise FarmConfigError(f"{path}: cannot read farm config: {e}") from None


def _read_file(path: Path, named: bool = False) -> dict:
    """The settings in the TOML file ``path``; none when it does not exist, unless the user
    ``named`` it (``TWEEN_FARM_CONFIG``): a file named and missing is an error, not silence.
    ``/dev/null`` (no file) is no settings; a folder or another non-file is an error."""
    data = _open_file(path, named)
    if data is None:
        return {}
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
    if roots and not all(r.strip() for r in roots):
        raise FarmConfigError(f"{path}: shot_roots: an empty folder path in {roots!r}")
    return data


def embedded_urls(folder: Path) -> tuple[str, str]:
    """Broker and result URLs of the server-less default, in ``folder``."""
    folder = folder.resolve()
    folder.mkdir(parents=True, exist_ok=True)
    return f"tweensqla+sqlite:///{folder / 'broker.sqlite'}", f"db+sqlite:///{folder / 'results.sqlite'}"


def _named(key: str, value, where: str) -> str:
    """The head of an error line about ``key``: ``TWEEN_<KEY>=value`` for a variable (URLs
    without their passwords), the file and key (``farm.toml: key``) for the file."""
    if not where.startswith("TWEEN_"):
        return where
    shown = redact_url(value) if key in _URL_KEYS else str(value)
    return f"{where}={shown if shown.strip() else repr(shown)}"


def _integer(key: str, raw, where: str):
    """The integer setting ``key``: a TOML integer in the file, plain decimal digits in the
    environment; within its bounds."""
    if where.startswith("TWEEN_"):
        ok, form = isinstance(raw, str) and _DIGITS.fullmatch(raw), "plain decimal digits"
    else:
        ok, form = type(raw) is int, "a TOML integer, without quotes"
    try:
        value = int(raw) if ok else None
    except ValueError:  # more digits than Python converts
        value = None
    if value is None:
        raise FarmConfigError(f"{where}: expected an integer, got {raw!r} ({form})")
    least, most = (0 if key == "max_retries" else 1), _MOST.get(key)
    if value < least:
        raise FarmConfigError(f"{where}: must be {least} or more, got {value}")
    if most is not None and value > most:
        unit = " ms" if key == "render_frame_ms" else " s (7 days)"
        raise FarmConfigError(f"{where}: must be at most {most}{unit}, got {value}")
    return value


def _string(key: str, raw: str, where: str) -> str:
    """The string setting ``key``: not blank (an empty optional one is none, its default);
    a queue not one of the embedded farm's."""
    if not raw.strip():
        if raw == "" and key in _PATH_KEYS:
            return raw
        raise FarmConfigError(f"{_named(key, raw, where)}: empty; give {key} a value, or leave it out")
    if key in _QUEUE_KEYS and raw.startswith(EMBEDDED_QUEUE_PREFIX):
        raise FarmConfigError(
            f"{_named(key, raw, where)}: queue names starting with {EMBEDDED_QUEUE_PREFIX} are the embedded "
            "farm's private queues (their jobs count as a dead client's once it exits); choose another name"
        )
    return raw


def _given(env, data: dict, key: str, file: Path) -> tuple[object, str] | None:
    """The value of ``key`` given in ``env`` (first; an empty variable is none) or in the file's
    ``data``, and where it came from; None when neither gives it."""
    name = f"TWEEN_{key.upper()}"
    if env.get(name):
        return env[name], name
    if key in data:
        return data[key], f"{file}: {key}"
    return None


def _env_roots(roots: str) -> tuple[str, ...]:
    """The folders of ``TWEEN_SHOT_ROOTS``: separated by ``os.pathsep``, or a JSON list (for a
    folder whose name holds one: the embedded farm's were cut there, and a shot under
    ``sq:010`` refused as outside its roots); a blank one is refused, as the file's
    ``shot_roots = [""]`` is (" " was taken for a folder named so)."""
    if roots.lstrip().startswith("["):
        try:
            entries = json.loads(roots)
        except ValueError as e:
            raise FarmConfigError(f"TWEEN_SHOT_ROOTS={roots!r}: not a JSON list of folders: {e}") from None
        if not isinstance(entries, list) or not all(isinstance(r, str) for r in entries):
            raise FarmConfigError(f"TWEEN_SHOT_ROOTS={roots!r}: not a JSON list of folders")
    else:
        entries = roots.split(os.pathsep)
    if not all(r.strip() for r in entries):
        raise FarmConfigError(
            f"TWEEN_SHOT_ROOTS={roots!r}: an empty folder path in {entries!r} (folders separated by {os.pathsep!r})"
        )
    return tuple(entries)


def _values(env, data: dict) -> tuple[dict, dict[str, str]]:
    """Each setting given, from ``env`` (first) or the config file's ``data``, typed and
    checked, and where each came from (for the error lines). Relative paths of the file are
    relative to its folder, those of the environment to the working folder."""
    file = config_file(env)
    base = os.path.dirname(os.path.abspath(file))
    vals: dict = {}
    origin: dict[str, str] = {}  # where each given setting came from, for the error lines
    for key in _STR_KEYS + _INT_KEYS:
        got = _given(env, data, key, file)
        if got is None:
            continue
        raw, where = got
        origin[key] = where
        from_file = not where.startswith("TWEEN_")
        if key in _INT_KEYS:
            vals[key] = _integer(key, raw, where)
            continue
        vals[key] = _string(key, raw, where)
        if key in _PATH_KEYS and vals[key]:
            vals[key] = security.resolve_path(vals[key], base if from_file else None)
    roots = env.get("TWEEN_SHOT_ROOTS")
    if roots:
        vals["shot_roots"] = _env_roots(roots)
        origin["shot_roots"] = "TWEEN_SHOT_ROOTS"
    elif data.get("shot_roots"):
        vals["shot_roots"] = tuple(security.resolve_path(r, base) for r in data["shot_roots"])
        origin["shot_roots"] = f"{file}: shot_roots"
    return vals, origin


def _broker_and_backend(vals: dict, env, origin: dict[str, str]) -> tuple[str, str, bool]:
    """The broker and result backend URLs (taken out of ``vals``), and whether the farm is
    the embedded, server-less default (no broker given)."""
    broker = vals.pop("broker_url", None)
    backend = vals.pop("result_backend", None)
    embedded = broker is None
    if embedded:
        broker, default_backend = embedded_urls(cache_dir(env) / "farm")
        backend = backend or default_backend
    elif "://" not in broker:  # else read as a transport name, and refused for what it lacks
        raise FarmConfigError(
            f"{_named('broker_url', broker, origin['broker_url'])}: not a broker URL "
            "(redis://HOST:6379/0, rediss://..., amqp://USER@HOST//, amqps://...)"
        )
    elif backend is None:
        if broker.startswith(("redis://", "rediss://")):
            backend = broker
        else:
            raise FarmConfigError(
                f"{_named('broker_url', broker, origin['broker_url'])}: a non-Redis broker needs "
                "result_backend (TWEEN_RESULT_BACKEND) too: chords need a real result backend "
                "(redis://... or db+postgresql://...)"
            )
    if backend.startswith("rpc://"):
        raise FarmConfigError(
            f"{_named('result_backend', backend, origin.get('result_backend', 'TWEEN_RESULT_BACKEND'))}: "
            "rpc:// cannot run chords; use redis:// or db+..."
        )
    if "result_backend" in origin:  # the embedded default and a Redis broker's own are fine
        why = backends.problem(backend)
        for pw in url_passwords(backend) if why else ():
            why = why.replace(pw, "***")
        if why:
            raise FarmConfigError(f"{_named('result_backend', backend, origin['result_backend'])}: {why}")
    return broker, backend, embedded


def _lead(s: FarmSettings, origin: dict[str, str], *keys: str) -> str:
    """Where the given ones of ``keys`` came from (``TWEEN_<KEY>=value``, ``farm.toml: key``),
    for the head of an error line about how they agree."""
    given = [_named(k, getattr(s, k), origin[k]) for k in keys if k in origin]
    return ", ".join(given) or "the default farm settings"


def _below(s: FarmSettings, origin: dict[str, str], low: str, high: str, why: str = "") -> None:
    a, b = getattr(s, low), getattr(s, high)
    if a >= b:
        raise FarmConfigError(
            f"{_lead(s, origin, low, high)}: {low} ({a} s) must be below {high} ({b} s){why}"
        )


def _check_limits(s: FarmSettings, origin: dict[str, str] | None = None) -> None:
    """Time limits, heartbeat and queues that agree with each other (and with Redis's
    visibility timeouts, on a Redis farm); an error names where the values came from."""
    origin = origin or {}
    _below(s, origin, "fill_soft_time_limit", "fill_time_limit")
    _below(s, origin, "render_soft_time_limit", "render_time_limit")
    if s.is_redis:
        _below(s, origin, "fill_time_limit", "visibility_timeout",
               ", or Redis hands a running task to a second worker")  # fmt: skip
        if 3 * s.heartbeat_interval > s.visibility_timeout:
            raise FarmConfigError(
                f"{_lead(s, origin, 'heartbeat_interval', 'visibility_timeout')}: heartbeat_interval "
                f"({s.heartbeat_interval} s) must be at most a third of visibility_timeout "
                f"({s.visibility_timeout} s): a running stage renews its Redis lease at each heartbeat"
            )
        _below(s, origin, "train_time_limit", "train_visibility_timeout")
        _below(s, origin, "train_rig_time_limit", "train_rig_visibility_timeout",
               ", or Redis hands a running training to a second worker")  # fmt: skip
    names = [getattr(s, k) for k in _QUEUE_KEYS]
    if len(set(names)) < 3:
        same = [k for k in _QUEUE_KEYS if names.count(getattr(s, k)) > 1]
        raise FarmConfigError(
            f"{_lead(s, origin, *same)}: queue, train_queue and train_rig_queue must be three different queues"
        )


def load_settings(env: dict | None = None) -> FarmSettings:
    """Resolves the settings from ``env`` (default ``os.environ``) and the config file."""
    env = os.environ if env is None else env
    data = _read_file(config_file(env), named=bool(env.get("TWEEN_FARM_CONFIG")))
    vals, origin = _values(env, data)
    broker, backend, embedded = _broker_and_backend(vals, env, origin)
    s = FarmSettings(broker_url=broker, result_backend=backend, embedded=embedded, **vals)
    _check_limits(s, origin)
    try:
        security.check(s, origin)
    except security.FarmConfigError as e:
        raise FarmConfigError(str(e)) from None
    return s
