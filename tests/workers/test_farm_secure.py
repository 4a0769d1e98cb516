"""A secured farm, set up by the commands of docs/farm.md ("Securing the farm") as written,
with only the site's values (host, ports, folders, password) put in: the doc's `openssl`
commands make the CA, the broker's certificate and the signing key; the doc's Redis config
runs a real TLS Redis with a password (``redis-server`` built with TLS); the doc's farm
settings file drives a real ``tween worker`` and the ``tween`` commands.

Checked: signed jobs fill over TLS; unsigned, foreign-signed, forged and tampered jobs are
dropped by the worker and never run; clients without the password, the CA or TLS cannot
enqueue; bad security settings are one line; passwords and keys never show in logs,
``tween status``, error lines or the outputs. The ``amqps://`` set-up runs on a private
RabbitMQ node configured by the doc's RabbitMQ config and ``rabbitmqctl`` commands.
"""

from __future__ import annotations

import base64
import json
import os
import re
import shutil
import socket
import ssl
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
import redis
from redis_server import REPO, WorkerPool, copy_shot, example_shot

DOC = REPO / "docs" / "farm.md"
SITE_HOST = "broker.example.com"
TOML_HEAD = "# ~/.config/usd-tween/farm.toml"
REDIS_CONF_HEAD = "# /etc/redis/tween.conf"
RABBIT_CONF_HEAD = "# /etc/rabbitmq/conf.d/tween-tls.conf"


# --- the doc's commands --------------------------------------------------------------------


def _section() -> str:
    text = DOC.read_text()
    start = text.index("\n## Securing the farm\n")
    return text[start : text.index("\n## ", start + 5)]


def _blocks() -> list[str]:
    return re.findall(r"```[a-z]*\n(.*?)```", _section(), re.S)


def _block(first: str) -> str:
    """The code block of the section whose first line starts with ``first``."""
    found = [b for b in _blocks() if b.startswith(first)]
    assert len(found) == 1, f"docs/farm.md: no single block starting with {first!r}"
    return found[0]


def _run_doc_block(block: str, cwd: Path, subs: dict[str, str], env=None) -> None:
    for a, b in subs.items():
        assert a in block, f"docs/farm.md changed: {a!r} is no longer in the block"
        block = block.replace(a, b)
    res = subprocess.run(["bash", "-e", "-c", block], cwd=cwd, capture_output=True, text=True, env=env)
    assert res.returncode == 0, res.stderr[-2000:]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _openssl(*args: str, cwd: Path) -> str:
    res = subprocess.run(["openssl", *args], cwd=cwd, capture_output=True, text=True, check=True)
    return res.stdout


def _expired_cert(folder: Path) -> Path:
    """A self-signed RSA certificate that expired yesterday (openssl 3.0 cannot date one back)."""
    import datetime

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import rsa
    from cryptography.x509.oid import NameOID

    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "old farm signing")])
    now = datetime.datetime.now(datetime.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(days=30))
        .not_valid_after(now - datetime.timedelta(days=1))
        .sign(key, hashes.SHA256())
    )
    out = folder / "expired.pem"
    out.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return out


@pytest.fixture(scope="module")
def creds(tmp_path_factory):
    """The doc's credentials (broker host localhost, with 127.0.0.1 in its certificate: kombu
    connects to 127.0.0.1 when told localhost), plus an intruder's key and a forged certificate
    with the farm certificate's issuer and serial number but another key."""
    d = tmp_path_factory.mktemp("creds")
    t0 = time.monotonic()
    (first,) = [b for b in _blocks() if b.startswith("BROKER=")]
    _run_doc_block(
        first,
        d,
        {
            f"BROKER={SITE_HOST}": "BROKER=localhost",
            "subjectAltName=DNS:$BROKER": "subjectAltName=DNS:$BROKER,IP:127.0.0.1",
            "rsa:3072": "rsa:2048",  # test keys: quicker to make on busy cores, same commands
        },
    )
    for f in (
        "ca.pem",
        "broker.pem",
        "broker.key",
        "farm-signing.key",
        "farm-signing.pem",
        "broker.password",
    ):
        assert (d / f).is_file(), f
    assert (d / "farm-signing.key").stat().st_mode & 0o077 == 0
    key_args = ["-newkey", "rsa:2048", "-nodes", "-days", "30"]
    _openssl("req", "-x509", *key_args, "-subj", "/CN=intruder", "-keyout", "intruder.key", "-out", "intruder.pem", cwd=d)  # fmt: skip
    serial = _openssl("x509", "-in", "farm-signing.pem", "-noout", "-serial", cwd=d).strip().split("=")[1]
    _openssl("req", "-x509", *key_args, "-subj", "/CN=tween farm signing", "-set_serial", f"0x{serial}",
             "-keyout", "forged.key", "-out", "forged.pem", cwd=d)  # fmt: skip
    print(f"credentials: {time.monotonic() - t0:.1f} s")
    return SimpleNamespace(dir=d, password=(d / "broker.password").read_text().strip())


def _ping(url: str) -> bool:
    try:
        return bool(redis.Redis.from_url(url, socket_connect_timeout=1, socket_timeout=2).ping())
    except (redis.RedisError, OSError):
        return False


@pytest.fixture(scope="module")
def tls_redis(creds, tmp_path_factory):
    """The doc's Redis config and command, on a free port of 127.0.0.1."""
    d = tmp_path_factory.mktemp("redis")
    port = _free_port()
    conf = _block(REDIS_CONF_HEAD)
    for a, b in {
        "/etc/redis/tween/": f"{creds.dir}/",
        "tls-port 6380": f"tls-port {port}",
        "PASSWORD": creds.password,
        "bind 0.0.0.0": "bind 127.0.0.1",
    }.items():
        assert a in conf
        conf = conf.replace(a, b)
    (d / "tween.conf").write_text(conf + 'save ""\n')
    (cmd,) = [b for b in _blocks() if b.startswith("redis-server ")]
    cmd = cmd.replace("/etc/redis/tween.conf", str(d / "tween.conf")).strip()
    assert "\n" not in cmd
    proc = subprocess.Popen(cmd.split(), cwd=d, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    url = f"rediss://:{creds.password}@localhost:{port}/0?ssl_ca_certs={creds.dir}/ca.pem"
    for _ in range(100):
        if _ping(url):
            break
        if proc.poll() is not None:
            pytest.fail(
                f"redis-server does not start with the doc's TLS config: {proc.stdout.read()[-1500:]!r}"
            )
        time.sleep(0.05)
    else:
        proc.kill()
        pytest.fail("redis-server with TLS did not answer")
    yield SimpleNamespace(port=port, proc=proc, client=redis.Redis.from_url(url))
    proc.terminate()
    proc.wait(timeout=10)


def _base_env() -> dict[str, str]:
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith("TWEEN_") or k in ("TWEEN_CACHE", "TWEEN_DATA")
    }
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), str(REPO / "tests")])
    return env


@pytest.fixture(scope="module")
def farm(creds, tls_redis, rabbit_boot, tmp_path_factory):
    """The doc's farm settings file, and a real ``tween worker`` started from it."""
    root = tmp_path_factory.mktemp("shows")
    logs = tmp_path_factory.mktemp("seclogs")
    toml = _block(TOML_HEAD)
    for a, b in {
        "PASSWORD": creds.password,
        f"{SITE_HOST}:6380": f"localhost:{tls_redis.port}",
        "/etc/usd-tween/": f"{creds.dir}/",
        '"/shows"': json.dumps(str(root)),
    }.items():
        assert a in toml
        toml = toml.replace(a, b)
    cfg = creds.dir / "farm.toml"
    cfg.write_text(toml)
    cfg.chmod(0o600)
    env = {**_base_env(), "TWEEN_FARM_CONFIG": str(cfg)}
    pool = WorkerPool(env, logs)
    t0 = time.monotonic()
    worker = pool.start(concurrency=1)
    try:
        pool.wait_ready()
        print(f"signed TLS worker ready in {time.monotonic() - t0:.1f} s")
        yield SimpleNamespace(root=root, logs=logs, env=env, cfg=cfg, worker=worker, pool=pool, creds=creds,
                              redis=tls_redis, outputs=[])  # fmt: skip
    finally:
        pool.stop_all()


def _tween(*args: str, env: dict, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "pipeline.cli", *args], cwd=REPO, env=env, capture_output=True, text=True,
        timeout=timeout,
    )  # fmt: skip


def _tweens(calls: list[tuple[list[str], dict]]) -> list[subprocess.CompletedProcess]:
    """Several ``tween`` commands at once (each spends ~1 s importing)."""
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "pipeline.cli", *a],
            cwd=REPO,
            env=e,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )  # fmt: skip
        for a, e in calls
    ]
    out = []
    for (a, _), p in zip(calls, procs, strict=True):
        so, se = p.communicate(timeout=120)
        out.append(subprocess.CompletedProcess(a, p.returncode, so, se))
    return out


def _results_app(farm):
    """A client app on the farm's result backend (TLS, no signing: results are JSON), so
    this test process never registers a signing key."""
    from dataclasses import replace

    from celery import Celery

    from workers.app import configure
    from workers.settings import load_settings

    s = load_settings(farm.env)
    return configure(Celery("tween-secure-test"), replace(s, security_key="", security_certificate="",
                                                          security_cert_store=""))  # fmt: skip


def _stage_meta(app, job_id: str, takes: int) -> dict:
    from workers.jobs import stage_ids

    return {name: app.backend.get_task_meta(tid)["status"] for name, tid in stage_ids(job_id, takes)}


def _wait_success(app, job_id: str, takes: int, timeout: float = 90) -> None:
    t0 = time.monotonic()
    while True:
        st = _stage_meta(app, job_id, takes)
        if all(v == "SUCCESS" for v in st.values()):
            return
        assert "FAILURE" not in st.values(), st
        assert time.monotonic() - t0 < timeout, st
        time.sleep(0.3)


def _shot(farm, name: str) -> Path:
    return copy_shot(example_shot(), farm.root / name, name)


def _one_line_error(res) -> str:
    assert res.returncode == 2, (res.returncode, res.stdout, res.stderr)
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("tween: error: "), res.stderr
    return lines[0]


def _queue_keys(r: redis.Redis) -> dict[str, int]:
    return {k.decode(): r.llen(k) for k in r.scan_iter(count=1000) if r.type(k) == b"list"}


# --- settings and configuration (no server) -----------------------------------------------


def _senv(**kw) -> dict:
    return {"TWEEN_FARM_CONFIG": os.devnull, **{f"TWEEN_{k.upper()}": str(v) for k, v in kw.items()}}


def test_security_settings_are_checked_in_one_line(creds, tmp_path):
    from workers.settings import FarmConfigError, load_settings

    d = creds.dir
    rediss = "rediss://:pw@h:6380/0"
    signing = dict(security_key=d / "farm-signing.key", security_certificate=d / "farm-signing.pem",
                   security_cert_store=d / "farm-signing.pem")  # fmt: skip
    s = load_settings(_senv(broker_url=rediss, tls_ca_file=d / "ca.pem", **signing))
    assert s.security_key == str(d / "farm-signing.key") and s.tls_ca_file == str(d / "ca.pem")
    store = tmp_path / "store"
    store.mkdir()
    shutil.copy(d / "farm-signing.pem", store / "a.pem")
    shutil.copy(d / "forged.pem", store / "b.pem")
    expired = _expired_cert(tmp_path)
    (tmp_path / "junk.pem").write_text("not a certificate\n")
    cases = [
        (dict(broker_url=rediss, security_key=d / "farm-signing.key"),
         r"^security_certificate is missing: TWEEN_SECURITY_KEY is set"),
        (dict(broker_url=rediss, **{**signing, "security_key": d / "nope.key"}),
         rf"^TWEEN_SECURITY_KEY: {d}/nope.key: no such file$"),
        (dict(broker_url=rediss, **{**signing, "security_key": d / "farm-signing.pem"}),
         r"^TWEEN_SECURITY_KEY: .*farm-signing.pem: not a PEM RSA private key"),
        (dict(broker_url=rediss, **{**signing, "security_key": d / "intruder.key"}),
         r"^TWEEN_SECURITY_KEY: .*intruder.key is not the key of the certificate .*farm-signing.pem$"),
        (dict(broker_url=rediss, **{**signing, "security_cert_store": d / "intruder.pem"}),
         r"^TWEEN_SECURITY_CERT_STORE: .*intruder.pem lacks this host's own certificate"),
        (dict(broker_url=rediss, **{**signing, "security_cert_store": store}),
         r"^TWEEN_SECURITY_CERT_STORE: .*two certificates with one issuer and serial number$"),
        (dict(broker_url=rediss, **{**signing, "security_cert_store": tmp_path / "*.pem"}),
         r"^TWEEN_SECURITY_CERT_STORE: .*expired.pem: expired$"),
        (dict(broker_url=rediss, **{**signing, "security_cert_store": tmp_path / "none-*.pem"}),
         r"^TWEEN_SECURITY_CERT_STORE: .*none-\*.pem: no certificate files$"),
        (dict(broker_url=rediss, **{**signing, "security_certificate": expired}),
         r"^TWEEN_SECURITY_CERTIFICATE: .*expired.pem: expired$"),
        (dict(broker_url=rediss, security_digest="sha-1", **signing), r"^TWEEN_SECURITY_DIGEST: unknown digest"),
        (dict(broker_url="redis://h/0", tls_ca_file=d / "ca.pem"),
         r"^TWEEN_TLS_CA_FILE: set, but neither the broker nor the result backend uses TLS"),
        (dict(broker_url=rediss, tls_ca_file=tmp_path / "junk.pem"),
         r"^TWEEN_TLS_CA_FILE: .*junk.pem: not a PEM CA certificate file"),
        (dict(broker_url=rediss + "?ssl_cert_reqs=none"),
         r"^TWEEN_BROKER_URL: ssl_cert_reqs=none does not check the server's certificate"),
        (dict(broker_url=rediss, result_backend=rediss + "?ssl_cert_reqs=CERT_OPTIONAL"),
         r"^TWEEN_RESULT_BACKEND: ssl_cert_reqs=CERT_OPTIONAL does not check"),
        (dict(broker_url=rediss + "?ssl_check_hostname=false"),
         r"^TWEEN_BROKER_URL: ssl_check_hostname=false accepts any certificate"),
        (dict(broker_url=rediss + f"?ssl_ca_certs={d}/ca.pem", tls_ca_file=d / "ca.pem"),
         r"^TWEEN_BROKER_URL: the URL's ssl_ca_certs and tls_ca_file both name a CA"),
        (dict(broker_url=rediss + "?ssl_cert_reqs=required&ssl_ca_certs=/nope/ca.pem"),
         r"^TWEEN_BROKER_URL \(ssl_ca_certs\): /nope/ca.pem: no such file$"),
        (dict(broker_url=f"amqps://tween:pw@h:5671//?ssl_ca_certs={d}/ca.pem", result_backend=rediss),
         r"^TWEEN_BROKER_URL: amqps:// takes no ssl_ca_certs URL parameter"),
    ]  # fmt: skip
    for kw, pattern in cases:
        with pytest.raises(FarmConfigError) as e:
            load_settings(_senv(**kw))
        msg = str(e.value)
        assert "\n" not in msg and re.search(pattern, msg), (kw, msg)
        assert "pw@" not in msg
    # A URL's own CA (the Celery way) is accepted once, checked like the setting.
    load_settings(_senv(broker_url=rediss + f"?ssl_cert_reqs=required&ssl_ca_certs={d}/ca.pem"))
    # In the settings file: relative paths are relative to its folder, errors name file and key.
    cfg = d / "rel.toml"
    cfg.write_text(f'broker_url = "{rediss}"\ntls_ca_file = "ca.pem"\nsecurity_key = "farm-signing.key"\n'
                   'security_certificate = "farm-signing.pem"\nsecurity_cert_store = "."\n')  # fmt: skip
    with pytest.raises(
        FarmConfigError,
        match=rf"^{cfg}: security_cert_store: {d}/broker.csr: not a PEM RSA certificate \(Valid PEM but no BEGIN CERTIFICATE",
    ):
        load_settings({"TWEEN_FARM_CONFIG": str(cfg)})  # the folder: every file in it
    cfg.write_text(cfg.read_text().replace('"."', '"farm-signing.pem"'))
    assert load_settings({"TWEEN_FARM_CONFIG": str(cfg)}).security_cert_store == str(d / "farm-signing.pem")
    cfg.write_text(cfg.read_text().replace('"farm-signing.key"', '"missing.key"'))
    with pytest.raises(FarmConfigError, match=rf"^{cfg}: security_key: {d}/missing.key: no such file$"):
        load_settings({"TWEEN_FARM_CONFIG": str(cfg)})


def test_configure_applies_tls_and_signing(creds):
    from celery import Celery
    from kombu.serialization import registry

    from workers.app import configure
    from workers.settings import load_settings, redact_url

    d = creds.dir
    signing = dict(security_key=d / "farm-signing.key", security_certificate=d / "farm-signing.pem",
                   security_cert_store=d / "farm-signing.pem", tls_ca_file=d / "ca.pem")  # fmt: skip
    app = Celery("tween-secure-conf")
    try:
        configure(app, load_settings(_senv(broker_url="rediss://:pw@h:6380/0", **signing)))
        c = app.conf
        assert c.task_serializer == "auth" and c.accept_content == ["auth"]
        assert c.result_serializer == "json" and c.result_accept_content == ["json"]
        assert c.security_key == str(d / "farm-signing.key") and c.security_digest == "sha256"
        tls = {"ssl_cert_reqs": ssl.CERT_REQUIRED, "ssl_ca_certs": str(d / "ca.pem")}
        assert c.broker_use_ssl == tls and c.redis_backend_use_ssl == tls
        s = load_settings(_senv(broker_url="rediss://:pw@h:6380/0", **signing))
        for kw in ({"train": True}, {"rig": True}):  # the training apps sign and verify alike
            other = configure(Celery("tween-secure-conf-" + next(iter(kw))), s, **kw).conf
            assert (
                other.task_serializer == "auth"
                and other.accept_content == ["auth"]
                and other.broker_use_ssl == tls
            )
        amqps = load_settings(_senv(broker_url="amqps://tween:pw@h:5671//", result_backend="rediss://:pw@h/0",
                                    **signing))  # fmt: skip
        configure(app, amqps)
        assert c.broker_use_ssl == {
            "cert_reqs": ssl.CERT_REQUIRED,
            "ca_certs": str(d / "ca.pem"),
            "server_hostname": None,
        }
        assert c.redis_backend_use_ssl == tls
        # Configured again without: plain JSON, no TLS options, no key.
        configure(app, load_settings(_senv(broker_url="redis://h/0")))
        assert c.task_serializer == "json" and c.accept_content == ["json"]
        assert c.broker_use_ssl is None and c.redis_backend_use_ssl is None and c.security_key is None
        # The embedded farm signs too when the keys are set (its worker reads the same settings).
        embedded = {k: v for k, v in signing.items() if k != "tls_ca_file"}
        configure(app, s := load_settings({**_senv(**embedded), "TWEEN_CACHE": str(creds.dir / "cache")}))
        assert s.embedded and c.task_serializer == "auth" and c.broker_use_ssl is None
        # TLS without a CA file: the system's CAs, still verified.
        configure(app, load_settings(_senv(broker_url="rediss://:pw@h:6380/0")))
        assert c.broker_use_ssl == {"ssl_cert_reqs": ssl.CERT_REQUIRED}
        # Passwords in URLs, also TLS ones and a client key's ssl_password, never printed.
        for url in ("rediss://:s3cr3t@h:6380/0?ssl_cert_reqs=required&ssl_ca_certs=/x/ca.pem",
                    "rediss://tween:s3cr3t@h:6380/0", "amqps://tween:s3cr3t@h:5671//",
                    "rediss://h:6380/0?ssl_keyfile=/k&ssl_password=s3cr3t"):  # fmt: skip
            assert "s3cr3t" not in redact_url(url) and "***" in redact_url(url), url
        assert "ssl_ca_certs=/x/ca.pem" in redact_url("rediss://:s3cr3t@h/0?ssl_ca_certs=/x/ca.pem")
        assert "s3cr3t" not in repr(load_settings(_senv(broker_url="rediss://:s3cr3t@h:6380/0")))
    finally:
        registry._set_default_serializer("json")  # setup_security made 'auth' this process's default


def test_bad_security_setting_stops_farm_commands_before_the_broker(creds, tmp_path):
    env = {**_base_env(), **_senv(broker_url="rediss://:pw@localhost:1/0",
                                  security_key=creds.dir / "missing.key",
                                  security_certificate=creds.dir / "farm-signing.pem",
                                  security_cert_store=creds.dir / "farm-signing.pem")}  # fmt: skip
    shot = copy_shot(example_shot(), tmp_path, "sh")
    t0 = time.monotonic()
    sub, work = _tweens([(["submit", str(shot)], env), (["worker", "-c", "1"], env)])
    for res in (sub, work):
        line = _one_line_error(res)
        assert line == f"tween: error: TWEEN_SECURITY_KEY: {creds.dir}/missing.key: no such file", line
    assert time.monotonic() - t0 < 30


# --- the secured Redis farm ---------------------------------------------------------------


def test_signed_jobs_fill_over_tls(farm):
    """The doc's `tween fill`, `tween submit` and `tween status` on the TLS farm."""
    t0 = time.monotonic()
    a, b = _shot(farm, "sh010"), _shot(farm, "sh020")
    fill, sub = _tweens([(["fill", str(a), "--takes", "2", "--no-progress"], farm.env),
                         (["submit", str(b), "--takes", "2"], farm.env)])  # fmt: skip
    assert fill.returncode == 0, fill.stderr
    layers = [w.rstrip(",") for w in fill.stdout.split() if ".tween." in w]
    assert layers and all(Path(p).is_file() for p in layers), fill.stdout
    assert sub.returncode == 0, sub.stderr
    (job_id,) = sub.stdout.split()
    app = _results_app(farm)
    _wait_success(app, job_id, 2)
    status = _tween("status", job_id, env=farm.env)
    assert status.returncode == 0 and "success" in status.stdout, status
    farm.outputs += [fill, sub, status]
    print(f"signed fill + submit/status over TLS: {time.monotonic() - t0:.1f} s")


def _tamper(raw: bytes, old: str, new: str) -> bytes:
    """A kombu Redis message whose signed body has ``old`` replaced by ``new``; the signature
    and everything else kept."""
    msg = json.loads(raw)
    assert msg["content-type"] == "application/data"  # the auth serializer's
    signed = base64.b64decode(base64.b64decode(msg["body"]))
    signer, signature, ctype, cenc, body = signed.split(b"\x00\x01", 4)
    assert old.encode() in body
    body = body.replace(old.encode(), new.encode())
    packed = b"\x00\x01".join([signer, signature, ctype, cenc, body])
    msg["body"] = base64.b64encode(base64.b64encode(packed)).decode()
    return json.dumps(msg).encode()


def test_unsigned_foreign_forged_and_tampered_jobs_are_refused(farm):
    d, r = farm.creds.dir, farm.redis.client
    t0 = time.monotonic()
    shots = {n: _shot(farm, n) for n in ("intruder", "forged", "unsigned", "tampered", "redirected", "good")}
    side = "tween.side"  # a queue no worker reads: the captured message
    intruder = {**farm.env, "TWEEN_SECURITY_KEY": str(d / "intruder.key"),
                "TWEEN_SECURITY_CERTIFICATE": str(d / "intruder.pem"), "TWEEN_SECURITY_CERT_STORE": str(d / "intruder.pem")}  # fmt: skip
    forged = {**farm.env, "TWEEN_SECURITY_KEY": str(d / "forged.key"),
              "TWEEN_SECURITY_CERTIFICATE": str(d / "forged.pem"), "TWEEN_SECURITY_CERT_STORE": str(d / "forged.pem")}  # fmt: skip
    # A client with the broker's password and CA but no signing key: its jobs are plain JSON.
    unsigned = {**_base_env(), "TWEEN_FARM_CONFIG": os.devnull, "TWEEN_SHOT_ROOTS": str(farm.root),
                "TWEEN_BROKER_URL": f"rediss://:{farm.creds.password}@localhost:{farm.redis.port}/0",
                "TWEEN_TLS_CA_FILE": str(d / "ca.pem")}  # fmt: skip
    res = _tweens([
        (["submit", str(shots["intruder"])], intruder),
        (["submit", str(shots["forged"])], forged),
        (["submit", str(shots["unsigned"])], unsigned),
        (["submit", str(shots["tampered"])], {**farm.env, "TWEEN_QUEUE": side}),
        (["submit", str(shots["good"])], farm.env),
    ])  # fmt: skip
    for x in res:
        assert x.returncode == 0, x.stderr
    names = ("intruder", "forged", "unsigned", "tampered", "good")
    ids = dict(zip(names, (x.stdout.strip() for x in res), strict=True))
    good = ids.pop("good")
    # The captured job, made to fill another shot, put on the workers' queue.
    side_key = next(k for k in _queue_keys(r) if k.endswith(side))
    raw = r.rpop(side_key)
    assert r.llen(side_key) == 0
    fill_key = side_key[: -len(side)] + "tween.fill"
    r.lpush(fill_key, _tamper(raw, str(shots["tampered"]), str(shots["redirected"])))
    app = _results_app(farm)
    _wait_success(app, good, 1, timeout=60)  # the worker goes on working between refusals
    while farm.worker.log_text().count("Can't decode message body") < 3 and time.monotonic() - t0 < 90:
        time.sleep(0.2)
    log = farm.worker.log_text()
    unsigned_lines = [ln for ln in log.splitlines() if "Received invalid task message" in ln]
    assert (
        len(unsigned_lines) == 1 and "untrusted content of type json (application/json)" in unsigned_lines[0]
    )
    refused = {
        m[1]: ln
        for ln in log.splitlines()
        if "Can't decode message body" in ln and (m := re.search(r"'id': '(\w+)\.validate'", ln))
    }
    assert sorted(refused) == sorted(ids[n] for n in ("intruder", "forged", "tampered")), refused
    assert "Unknown certificate" in refused[ids["intruder"]]  # its certificate is not in the store
    for name in ("forged", "tampered"):  # Celery 5.7 words a bad signature as this TypeError
        assert re.search(r"Bad signature|catching classes that do not inherit", refused[ids[name]]), name
    assert _queue_keys(r).get(fill_key, 0) == 0  # dropped, not requeued
    assert not r.hlen(side_key[: -len(side)] + "unacked")
    for name in ("intruder", "forged", "unsigned", "tampered", "redirected"):
        assert not (farm.root / name / "out").exists() and not list((farm.root / name).glob("*.tween*")), name
    for name, job_id in ids.items():
        st = _stage_meta(app, job_id, 1)
        assert set(st.values()) == {"PENDING"}, (name, st)  # no stage ever started
    status = _tween("status", ids["intruder"], env=farm.env)
    assert status.returncode == 0 and "queued" in status.stdout.lower() and "success" not in status.stdout
    farm.outputs += [*res, status]
    print(f"four refused jobs and a good one: {time.monotonic() - t0:.1f} s")


def _outgoing_ip() -> str:
    """This host's address on its network (not loopback): what another host would reach."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.connect(("192.0.2.1", 9))  # no packet is sent: only picks the interface
        ip = s.getsockname()[0]
    assert not ip.startswith("127."), "this host has no network address to test from"
    return ip


def test_plain_broker_line_of_the_doc_answers_other_hosts(tmp_path):
    """docs/farm.md "Running a farm" starts a password-less Redis for a closed network: it must
    answer a client that comes from another address (Redis 7's protected mode refuses such
    clients unless told not to: the doc's line once lacked --protected-mode no)."""
    text = DOC.read_text()
    block = text[text.index("\n## Running a farm\n") :]
    block = re.search(r"```bash\n(.*?)```", block, re.S)[1]
    (line,) = [ln.split("#")[0].strip() for ln in block.splitlines() if ln.startswith("redis-server ")]
    port, ip = _free_port(), _outgoing_ip()
    for flags, answers in (
        (line.split()[1:], True),
        ([f for f in line.split()[1:] if f not in ("--protected-mode", "no")], False),
    ):
        proc = subprocess.Popen([shutil.which("redis-server"), *flags, "--port", str(port), "--save", ""], cwd=tmp_path,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
        try:
            for _ in range(100):
                if _ping(f"redis://127.0.0.1:{port}/0"):
                    break
                time.sleep(0.05)
            client = redis.Redis(host=ip, port=port, socket_timeout=2)
            if answers:
                assert client.ping()
            else:
                with pytest.raises(redis.RedisError, match="DENIED"):
                    client.ping()
        finally:
            proc.terminate()
            proc.wait(timeout=10)


def test_unsigned_remote_control_is_ignored(farm):
    """Remote control (ping, shutdown, …) uses the task serializer: a worker answers a signed
    ping and ignores unsigned commands, shutdown included."""
    from celery import Celery

    from workers.app import configure
    from workers.settings import load_settings

    d = farm.creds.dir
    plain = load_settings({"TWEEN_FARM_CONFIG": os.devnull, "TWEEN_TLS_CA_FILE": str(d / "ca.pem"),
                           "TWEEN_BROKER_URL": f"rediss://:{farm.creds.password}@localhost:{farm.redis.port}/0"})  # fmt: skip
    app = configure(Celery("tween-secure-unsigned-control"), plain)
    assert app.control.ping(timeout=1.5) == []  # unsigned: no answer
    app.control.broadcast("shutdown")
    code = "from workers.app import app; print(len(app.control.ping(timeout=5, limit=1)))"
    res = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=farm.env, capture_output=True, text=True,
                         timeout=60)  # fmt: skip
    assert res.returncode == 0 and res.stdout.split()[-1] == "1", res.stderr[
        -2000:
    ]  # signed: the worker answers
    assert farm.worker.proc.poll() is None  # still running after the unsigned shutdown


def test_unauthenticated_clients_cannot_enqueue(farm, tmp_path):
    from celery import Celery

    from workers.app import check_broker, configure
    from workers.errors import FarmConnectionError
    from workers.settings import load_settings

    d, port, r = farm.creds.dir, farm.redis.port, farm.redis.client
    before = _queue_keys(r)
    # No password, and a wrong one, through `tween submit`: one line each, no secret in it.
    shot = _shot(farm, "noauth")
    wrong = "wrong-" + farm.creds.password[:6]
    nopw, badpw = _tweens([
        (["submit", str(shot)], {**farm.env, "TWEEN_BROKER_URL": f"rediss://localhost:{port}/0"}),
        (["submit", str(shot)], {**farm.env, "TWEEN_BROKER_URL": f"rediss://:{wrong}@localhost:{port}/0"}),
    ])  # fmt: skip
    line = _one_line_error(nopw)
    assert f"broker rediss://localhost:{port}/0: cannot connect" in line and "authenticat" in line.lower(), (
        line
    )
    line = _one_line_error(badpw)
    assert "cannot connect" in line and wrong not in line and ":***@" in line, line
    # A raw client without the password, without the CA, or without TLS.
    with pytest.raises(redis.AuthenticationError):
        redis.Redis.from_url(f"rediss://localhost:{port}/0?ssl_ca_certs={d}/ca.pem").lpush(
            "tween:tween.fill", "x"
        )
    for env, why in (
        (
            _senv(broker_url=f"rediss://:{farm.creds.password}@localhost:{port}/0"),
            "certificate verify failed",
        ),
        (_senv(broker_url=f"redis://:{farm.creds.password}@localhost:{port}/0"), ""),
    ):
        app = configure(Celery("tween-secure-noauth"), load_settings(env))
        with pytest.raises(FarmConnectionError) as e:
            check_broker(app, timeout=1.0)
        assert why in str(e.value) and farm.creds.password not in str(e.value) and "\n" not in str(e.value)
    assert _queue_keys(r) == before
    farm.outputs += [nopw, badpw]


def test_secrets_never_in_logs_status_errors_or_outputs(farm, tmp_path):
    """After the tests above: the worker's logs, every command's output and every file the
    jobs wrote hold neither the password nor any key. Run without them (``-k``, another
    order), it makes the activity it audits first, by running them."""
    if len(farm.outputs) < 9:
        farm.outputs.clear()
        test_signed_jobs_fill_over_tls(farm)
        test_unsigned_foreign_forged_and_tampered_jobs_are_refused(farm)
        test_unauthenticated_clients_cannot_enqueue(farm, tmp_path)
    d = farm.creds.dir
    secrets = {"password": farm.creds.password}
    for f in ("farm-signing.key", "intruder.key", "forged.key", "broker.key", "ca.key"):
        secrets[f] = (d / f).read_text().splitlines()[1]  # a line of the key's base64
    texts = {str(p): p.read_text(errors="replace") for p in farm.logs.iterdir()}
    texts.update({f"tween {' '.join(map(str, o.args))}": o.stdout + o.stderr for o in farm.outputs})
    texts.update({str(p): p.read_bytes().decode("latin-1") for p in farm.root.rglob("*") if p.is_file()})
    assert len(farm.outputs) >= 9 and any(".tween" in t for t in texts)
    for where, text in texts.items():
        for what, secret in secrets.items():
            assert secret not in text, f"{what} in {where}"
    out = farm.worker.log.with_suffix(".out").read_text()
    assert f"tween worker: rediss://:***@localhost:{farm.redis.port}/0 queue tween.fill" in out, out[:500]


# --- RabbitMQ over TLS with a user ------------------------------------------------------------


def _amqp_up(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=1).close()
        return True
    except OSError:
        return False


@pytest.fixture(scope="module")
def rabbit_boot(creds):
    """A private RabbitMQ node (its own name, ports and data) with the doc's TLS listener
    config, started early (the ``farm`` fixture asks for it) so that its boot overlaps the
    Redis tests; ``wait()`` waits for it and runs the doc's ``rabbitmqctl`` commands."""
    exe = shutil.which("rabbitmq-server")
    # The node runs as the rabbitmq user: its files are not under pytest's 0700 tmp folder.
    d = Path(tempfile.mkdtemp(prefix="tween-rmq-"))
    d.chmod(0o755)
    for f in ("ca.pem", "broker.pem", "broker.key"):
        shutil.copy(creds.dir / f, d / f)
        (d / f).chmod(0o644)
    port, dist = _free_port(), _free_port()
    conf = _block(RABBIT_CONF_HEAD)
    for a, b in {
        "/etc/rabbitmq/tween/": f"{d}/",
        "listeners.ssl.default = 5671": f"listeners.ssl.default = {port}",
    }.items():
        assert a in conf
        conf = conf.replace(a, b)
    (d / "rabbitmq.conf").write_text(conf)
    (d / "enabled_plugins").write_text("[].\n")
    for sub in ("mnesia", "log"):
        (d / sub).mkdir()
        (d / sub).chmod(0o777)
    env = {**os.environ, "RABBITMQ_NODENAME": f"tween-tls-{port}@localhost", "RABBITMQ_NODE_PORT": str(_free_port()),
           "RABBITMQ_DIST_PORT": str(dist), "RABBITMQ_CONFIG_FILE": str(d / "rabbitmq.conf"),
           "RABBITMQ_MNESIA_BASE": str(d / "mnesia"), "RABBITMQ_LOG_BASE": str(d / "log"),
           "RABBITMQ_ENABLED_PLUGINS_FILE": str(d / "enabled_plugins"), "RABBITMQ_PID_FILE": str(d / "pid")}  # fmt: skip
    t0 = time.monotonic()
    out = open(d / "server.out", "wb")
    proc = None
    if exe:
        proc = subprocess.Popen([exe], env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
    state = {"ready": False}

    def wait() -> int:
        assert proc is not None, "rabbitmq-server is not installed (apt-get install rabbitmq-server)"
        if not state["ready"]:
            while not _amqp_up(port):
                assert proc.poll() is None, (d / "server.out").read_text()[-2000:]
                assert time.monotonic() - t0 < 90, "the private RabbitMQ node did not open its TLS port"
                time.sleep(0.3)
            (users,) = [b for b in _blocks() if b.startswith("rabbitmqctl add_user")]
            _run_doc_block(users, creds.dir, {}, env=env)
            state["ready"] = True
            print(
                f"private RabbitMQ node with TLS and its user, {time.monotonic() - t0:.1f} s after its start"
            )
        return port

    try:
        yield SimpleNamespace(wait=wait)
    finally:
        if proc is not None:
            subprocess.run(["rabbitmqctl", "stop"], env=env, capture_output=True, timeout=60)
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, 9)
                proc.wait()
        out.close()
        shutil.rmtree(d, ignore_errors=True)


def test_amqps_farm_with_a_user(farm, rabbit_boot, tmp_path):
    """The doc's RabbitMQ set-up: amqps:// with the farm's user, the TLS Redis as the result
    backend, signed jobs; guest and a wrong password are refused."""
    from celery import Celery

    from workers.app import check_broker, configure
    from workers.errors import FarmConnectionError
    from workers.settings import load_settings

    pw, port = farm.creds.password, rabbit_boot.wait()
    amqps = f"amqps://tween:{pw}@localhost:{port}//"
    env = {**farm.env, "TWEEN_BROKER_URL": amqps, "TWEEN_QUEUE": "tween.fill.amqps",
           "TWEEN_RESULT_BACKEND": f"rediss://:{pw}@localhost:{farm.redis.port}/0"}  # fmt: skip
    for url in (f"amqps://guest:guest@localhost:{port}//", f"amqps://tween:wrong{pw[:4]}@localhost:{port}//"):
        app = configure(Celery("tween-secure-amqps"), load_settings({**env, "TWEEN_BROKER_URL": url}))
        with pytest.raises(FarmConnectionError, match="ACCESS_REFUSED") as e:
            check_broker(app, timeout=2.0)
        assert pw not in str(e.value) and "\n" not in str(e.value)
    pool = WorkerPool(env, tmp_path)
    try:
        pool.start(concurrency=1)
        pool.wait_ready()
        shot = _shot(farm, "amqps")
        fill = _tween("fill", str(shot), "--takes", "1", "--no-progress", env=env)
        assert fill.returncode == 0, fill.stderr
        assert any(Path(w.rstrip(",")).is_file() for w in fill.stdout.split() if ".tween." in w), fill.stdout
        out = (tmp_path / f"{pool.workers[0].name}.out").read_text()
        assert f"amqps://tween:***@localhost:{port}//" in out and pw not in out
        assert pw not in pool.workers[0].log_text() and pw not in fill.stdout + fill.stderr
    finally:
        pool.stop_all()
