"""A secured farm: TLS to the broker and result backend, and signed job messages.

Two independent layers, both set in the farm settings (docs/farm.md, "Securing the farm"):

* **TLS** follows the URL's scheme (``rediss://``, ``amqps://``). The server's certificate is
  always verified (``CERT_REQUIRED``, host name checked), against ``tls_ca_file`` when it is
  set, else against the system's CAs; a URL that turns the check off is refused.
* **Signing** (``security_key``, ``security_certificate``, ``security_cert_store``): every task
  message is serialized by Celery's ``auth`` serializer, signed with the host's key, and a
  worker accepts only messages whose signature verifies against a certificate of the store.
  Unsigned, tampered and foreign-signed messages are dropped with a log line.

Every file a setting names is read and checked here, when the settings are loaded, so a bad
one is one line naming the setting and the file before any farm starts.
"""

from __future__ import annotations

import glob
import os
import re
import ssl
from urllib.parse import parse_qsl, unquote, urlsplit


class FarmConfigError(ValueError):
    """A bad TLS or signing setting (workers.settings raises it as its own FarmConfigError;
    this module is imported by it, so it does not import it back)."""


#: The three settings message signing needs, all or none.
SIGNING_KEYS = ("security_key", "security_certificate", "security_cert_store")
#: The path-valued settings of this module.
PATH_KEYS = ("tls_ca_file", *SIGNING_KEYS)
#: ``ssl_cert_reqs`` values that do not verify the server.
_UNVERIFIED = {"none", "cert_none", "optional", "cert_optional"}
#: URL query parameters that name files (redis-py / kombu).
_FILE_PARAMS = ("ssl_ca_certs", "ssl_certfile", "ssl_keyfile")


def resolve_path(value: str, base: str | None = None) -> str:
    """A path setting made absolute: ``~`` expanded; relative to ``base`` (the config file's
    folder) when it came from the file, else to the working folder."""
    p = os.path.expanduser(value)
    if base and not os.path.isabs(p):
        p = os.path.join(base, p)
    return os.path.abspath(p)


def _scheme(url: str) -> str:
    return str(url).split("://", 1)[0].lower() if "://" in str(url) else ""


def uses_tls(url: str) -> bool:
    return _scheme(url) in ("rediss", "amqps")


def tls_options(url: str, ca_file: str) -> dict | None:
    """The ``broker_use_ssl`` / ``redis_backend_use_ssl`` dict for ``url``, or None without TLS.

    Redis (redis-py) and AMQP (py-amqp) name the same options differently. A ``rediss://``
    URL's own ``ssl_*`` parameters, when it has any, are used by kombu/Celery instead
    (checked by :func:`check`)."""
    scheme = _scheme(url)
    if scheme == "rediss":
        return {"ssl_cert_reqs": ssl.CERT_REQUIRED, **({"ssl_ca_certs": ca_file} if ca_file else {})}
    if scheme == "amqps":
        # server_hostname None: kombu fills in the URL's host, so py-amqp checks the name.
        return {"cert_reqs": ssl.CERT_REQUIRED, "ca_certs": ca_file or None, "server_hostname": None}
    return None


def celery_conf(s) -> dict:
    """The Celery settings for TLS and signing of the farm settings ``s`` (all of them, also
    when off, so that configuring an app again with other settings undoes them)."""
    backend_tls = (
        tls_options(s.result_backend, s.tls_ca_file) if _scheme(s.result_backend) == "rediss" else None
    )
    conf = {
        "broker_use_ssl": tls_options(s.broker_url, s.tls_ca_file),
        "redis_backend_use_ssl": backend_tls,
        "security_key": None,
        "security_certificate": None,
        "security_cert_store": None,
    }
    if signed(s):
        conf.update(
            security_key=s.security_key,
            security_certificate=s.security_certificate,
            security_cert_store=s.security_cert_store,
            security_digest=s.security_digest,
            task_serializer="auth",
            accept_content=["auth"],
            # Results stay JSON (decoding JSON runs no code); the result backend is protected
            # by its password and TLS. Remote control messages use task_serializer: signed too.
            result_serializer="json",
            result_accept_content=["json"],
        )
    return conf


def signed(s) -> bool:
    return bool(s.security_key)


def apply(app, s) -> None:
    """Applies :func:`celery_conf` to ``app`` and, with signing, registers the ``auth``
    serializer with this host's key (kombu's serializer registry is one per process)."""
    app.conf.update(celery_conf(s))
    if signed(s):
        # Leaves JSON (and 'auth', registered right after) the only decoders of the process;
        # 'auth' signs and verifies JSON bodies.
        app.setup_security(allowed_serializers=["json"], serializer="json")


# --- checks ------------------------------------------------------------------------------


def _readable(where: str, path: str) -> str:
    """The text of the file ``path``, or a one-line error naming the setting and the file."""
    if not os.path.exists(path):
        raise FarmConfigError(f"{where}: {path}: no such file")
    if not os.path.isfile(path):
        raise FarmConfigError(f"{where}: {path}: not a file")
    try:
        with open(path, encoding="ascii", errors="replace") as f:
            return f.read()
    except OSError as e:
        raise FarmConfigError(f"{where}: {path}: cannot read: {e.strerror or e}") from None


def _check_ca(where: str, path: str) -> None:
    _readable(where, path)
    try:
        ssl.create_default_context(cafile=path)
    except (ssl.SSLError, ValueError) as e:
        raise FarmConfigError(f"{where}: {path}: not a PEM CA certificate file ({e})") from None


def _check_url(where: str, url: str, ca_file: str) -> None:
    """A TLS URL's own ``ssl_*`` parameters: never one that turns verification off, files that
    exist, and the CA in one place only."""
    if "?" not in str(url):
        return
    query = dict(parse_qsl(urlsplit(str(url)).query))
    ssl_params = sorted(k for k in query if k.startswith("ssl_"))
    if not ssl_params:
        return
    if _scheme(url) == "amqps":
        raise FarmConfigError(
            f"{where}: amqps:// takes no {ssl_params[0]} URL parameter (py-amqp does not read it); "
            "name the CA in tls_ca_file"
        )
    reqs = query.get("ssl_cert_reqs")
    if reqs is not None and reqs.lower() in _UNVERIFIED:
        raise FarmConfigError(
            f"{where}: ssl_cert_reqs={reqs} does not check the server's certificate; leave it out "
            "and name the CA that signed it in tls_ca_file"
        )
    if query.get("ssl_check_hostname", "").lower() == "false":
        raise FarmConfigError(
            f"{where}: ssl_check_hostname=false accepts any certificate the CA signed, for any host; "
            "give the broker a certificate with its name (subjectAltName)"
        )
    if "ssl_ca_certs" in query and ca_file:
        raise FarmConfigError(
            f"{where}: the URL's ssl_ca_certs and tls_ca_file both name a CA; keep one (tls_ca_file)"
        )
    for key in _FILE_PARAMS:
        if key in query:
            _readable(f"{where} ({key})", unquote(query[key]))


def check(s, where: dict[str, str]) -> None:
    """Checks the TLS and signing settings of ``s``; ``where[key]`` says where a setting came
    from (``TWEEN_SECURITY_KEY`` or ``farm.toml: security_key``) for the error line."""

    def at(key: str) -> str:
        return where.get(key, key)

    tls_urls = [u for u in (s.broker_url, s.result_backend) if uses_tls(u)]
    if s.tls_ca_file:
        _check_ca(at("tls_ca_file"), s.tls_ca_file)
        if not tls_urls:
            raise FarmConfigError(
                f"{at('tls_ca_file')}: set, but neither the broker nor the result backend uses TLS "
                "(rediss://, amqps://)"
            )
    for key, url in (("broker_url", s.broker_url), ("result_backend", s.result_backend)):
        if uses_tls(url):
            _check_url(at(key), url, s.tls_ca_file)
    given = [k for k in SIGNING_KEYS if getattr(s, k)]
    if given and len(given) < len(SIGNING_KEYS):
        missing = next(k for k in SIGNING_KEYS if not getattr(s, k))
        raise FarmConfigError(
            f"{missing} is missing: {at(given[0])} is set, and message signing needs security_key, "
            "security_certificate and security_cert_store"
        )
    if given:
        check_signing(s, at)


def _cert_files(store: str) -> list[str]:
    """The files of a certificate store the way Celery reads it: a folder (every file in it),
    a file, or a glob pattern."""
    pattern = os.path.join(store, "*") if os.path.isdir(store) else store
    return sorted(p for p in glob.glob(pattern) if os.path.isfile(p))


def check_signing(s, at) -> None:
    """The key, its certificate and the store, read as Celery's ``auth`` serializer will."""
    try:
        from celery.exceptions import SecurityError
        from celery.security.certificate import Certificate
        from celery.security.key import PrivateKey
        from cryptography.hazmat.primitives import hashes
    except ImportError as e:
        raise FarmConfigError(
            f"{at('security_key')}: message signing needs the {e.name or 'cryptography'} package "
            "(pip install 'usd-tween[secure]')"
        ) from None

    def load(cls, where, path, what):
        text = _readable(where, path)
        try:
            return cls(text)
        except (SecurityError, ValueError, TypeError) as e:
            why = str(e).split(": ", 1)[-1]
            why = re.sub(r"^\w+\((['\"])(.*)\1\)$", r"\2", why)  # ValueError('...') -> ...
            raise FarmConfigError(f"{where}: {path}: not a PEM RSA {what} ({why})") from None

    digest = s.security_digest
    if not isinstance(getattr(hashes, digest.upper(), None), type):
        raise FarmConfigError(f"{at('security_digest')}: unknown digest {digest!r} (e.g. sha256, sha512)")
    key = load(PrivateKey, at("security_key"), s.security_key, "private key (unencrypted)")
    cert = load(Certificate, at("security_certificate"), s.security_certificate, "certificate")
    if cert.has_expired():
        raise FarmConfigError(f"{at('security_certificate')}: {s.security_certificate}: expired")
    if key._key.public_key().public_numbers() != cert.get_pubkey().public_numbers():
        raise FarmConfigError(
            f"{at('security_key')}: {s.security_key} is not the key of the certificate {s.security_certificate}"
        )
    files = _cert_files(s.security_cert_store)
    if not files:
        raise FarmConfigError(f"{at('security_cert_store')}: {s.security_cert_store}: no certificate files")
    ids: dict[str, tuple[str, object]] = {}
    for path in files:
        c = load(Certificate, at("security_cert_store"), path, "certificate")
        if c.has_expired():
            raise FarmConfigError(f"{at('security_cert_store')}: {path}: expired")
        if c.get_id() in ids:
            raise FarmConfigError(
                f"{at('security_cert_store')}: {path} and {ids[c.get_id()][0]}: two certificates with one "
                "issuer and serial number"
            )
        ids[c.get_id()] = (path, c)
    own = ids.get(cert.get_id())
    if own is None or own[1].get_pubkey().public_numbers() != cert.get_pubkey().public_numbers():
        raise FarmConfigError(
            f"{at('security_cert_store')}: {s.security_cert_store} lacks this host's own certificate "
            f"{s.security_certificate} (workers verify the messages they send themselves)"
        )
