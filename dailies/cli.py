"""The dailies commands: ``tween dailies SHOT_ROOT...`` (the review page for the fills under
the roots), and ``tween approve`` / ``tween publish`` (the same decisions from a shell; publish
can also send the approved take to the studio's tracker)."""

from __future__ import annotations

import ipaddress
import json
import os
import re
import socket
import ssl
import sys
import threading
from pathlib import Path

import typer

from dailies.auth import Login, new_token
from dailies.shots import listing
from dailies.tracker import approved_of, read_mapping, send_take
from dailies.trackers import make
from pipeline.errors import TweenError
from pipeline.inputs import not_a_file

DEFAULT_HOST, DEFAULT_PORT = "127.0.0.1", 8765


def check_roots(roots: list[Path]) -> list[Path]:
    """The roots as absolute folders (links kept: media are checked against both)."""
    out = []
    for r in roots:
        if not r.exists():
            raise TweenError(f"{r}: no such folder")
        if not r.is_dir():
            raise TweenError(f"{r}: not a folder (give the folders the shots are under)")
        out.append(Path(os.path.abspath(r)))
    return out


def _loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_tls(certfile: Path | None, keyfile: Path | None) -> None:
    if (certfile is None) != (keyfile is None):
        raise TweenError(
            "--certfile and --keyfile: give both (the certificate and its private key) or neither"
        )
    for opt, p, kind in (("--certfile", certfile, "TLS certificate"), ("--keyfile", keyfile, "private key")):
        why = None if p is None else not_a_file(p, kind)
        if why is not None:  # a pipe would hold the TLS load for ever
            raise TweenError(f"{opt} {p}: {'no such file' if why == 'file not found' else why}")
    if certfile is not None:  # a bad pair is one line now, not a traceback once serving
        try:
            ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER).load_cert_chain(str(certfile), str(keyfile))
        except (ssl.SSLError, OSError) as e:
            raise TweenError(
                f"--certfile {certfile} --keyfile {keyfile}: cannot load: {e.strerror or e}"
            ) from None


def bind(host: str, port: int) -> socket.socket:
    """A listening socket on ``host:port`` (port 0: any free one), or one line saying why not."""
    if not 0 <= port <= 65535:
        raise TweenError(f"--port {port}: must be from 0 to 65535")
    try:
        info = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    except socket.gaierror as e:
        raise TweenError(f"--host {host}: {e.strerror}") from None
    sock = socket.socket(info[0], socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(info[4])
    except OSError as e:
        sock.close()
        raise TweenError(f"{host}:{port}: cannot listen there: {e.strerror} (another --port?)") from None
    sock.listen(128)
    sock.set_inheritable(True)
    return sock


def _warm(roots: list[Path]) -> None:
    try:
        listing(roots)
    except Exception:  # a cache warm-up only: the page reports what it finds itself
        pass


TRACKER_MAP_HELP = "JSON {shot file stem: {sequence, shot}} (default: SEQ_SHOT file names)."


def _tracker(name: str | None, mapping_file: Path | None):
    """(the tracker ``name`` made from its settings or None, the mapping read from
    ``mapping_file`` or None): every --tracker/--tracker-map mistake is one line here."""
    if mapping_file is not None and name is None:
        raise TweenError("--tracker-map: give --tracker too")
    mapping = read_mapping(mapping_file)
    return (make(name) if name else None), mapping


def dailies(
    roots: list[Path] = typer.Argument(..., help="Folders the shots and their fills are under."),
    host: str = typer.Option(
        DEFAULT_HOST, "--host", help="Address to listen on (default: this machine only)."
    ),
    port: int = typer.Option(DEFAULT_PORT, "--port", help="Port (0: any free one)."),
    certfile: Path = typer.Option(None, "--certfile", help="TLS certificate (PEM): serve https."),
    keyfile: Path = typer.Option(None, "--keyfile", help="The certificate's private key (PEM)."),
    token: str = typer.Option(
        None, "--token", envvar="TWEEN_DAILIES_TOKEN", help="Login token (default: a new one, in the URL)."
    ),
    tracker: str = typer.Option(
        None,
        "--tracker",
        help="Send approved takes to this tracker from the page: kitsu (TWEEN_KITSU_* settings).",
    ),
    tracker_map: Path = typer.Option(None, "--tracker-map", help=TRACKER_MAP_HELP),
):
    """Serve the dailies review page: takes side by side in sync, approve and publish."""
    # Everything checked before anything heavy is imported or the port is taken.
    roots = check_roots(roots)
    check_tls(certfile, keyfile)
    if token is not None and len(token) < 16:
        raise TweenError("--token (or TWEEN_DAILIES_TOKEN): at least 16 characters (it is the only login)")
    if token is not None and not re.fullmatch(r"[A-Za-z0-9._~-]+", token):  # spaces were taken
        raise TweenError(
            "--token (or TWEEN_DAILIES_TOKEN): letters, digits and . _ ~ - only (it goes in the URL as it is)"
        )
    sink, mapping = _tracker(tracker, tracker_map)  # its settings checked now, not at the first click
    import uvicorn

    from dailies.app import create_app

    tls = certfile is not None
    sock = bind(host, port)  # a bad --host or a taken port is the only line
    if not _loopback(host) and not tls:
        print(f"tween: dailies: warning: listening on {host} without TLS: the login token and the pages "
              "cross the network in clear (use --certfile/--keyfile)", file=sys.stderr)  # fmt: skip
    login = Login(token or new_token(), secure=tls)
    name = socket.gethostname() if host in ("0.0.0.0", "::") else host
    shown = f"[{name}]" if ":" in name else name
    url = f"{'https' if tls else 'http'}://{shown}:{sock.getsockname()[1]}/?token={login.token}"
    typer.echo(url)  # the first line of stdout: what to open
    sys.stdout.flush()
    print(f"tween: dailies: serving {', '.join(map(str, roots))}; Ctrl-C stops", file=sys.stderr)
    # Every layer's metadata read once now, so that the first page is as quick as the next.
    threading.Thread(target=_warm, args=(roots,), daemon=True).start()
    config = uvicorn.Config(
        create_app(roots, login, sink, mapping), log_level="warning", access_log=False,
        ssl_certfile=str(certfile) if tls else None, ssl_keyfile=str(keyfile) if tls else None,
    )  # fmt: skip
    uvicorn.Server(config).run(sockets=[sock])


OUT_DIR_HELP = "Folder of the fill layers (default: beside the shot)."


def approve(
    shot: Path = typer.Argument(..., help="USD shot whose latest fill is approved."),
    take: int = typer.Option(..., "--take", help="The approved take (0, 1, ...)."),
    note: str = typer.Option(None, "--note", help="The reviewer's note."),
    by: str = typer.Option(None, "--by", help="The reviewer's name (default: your login name)."),
    out_dir: Path = typer.Option(None, "--out-dir", help=OUT_DIR_HELP),
):
    """Dailies: record the approval of a take in a new fill layer version (and review layer)."""
    from pipeline.usd.dailies import approve as approve_take

    r = approve_take(str(shot), take, note=note, out_dir=str(out_dir) if out_dir else None, by=by)
    print(f"tween: approved take {r['take']} of {r['of']} -> {r['layer']}", file=sys.stderr)
    typer.echo(json.dumps(r, indent=1))


def publish(
    shot: Path = typer.Argument(..., help="USD shot whose approved take is published."),
    fmt: str = typer.Option(None, "--format", help="usda (default) or usdc."),
    out: str = typer.Option(  # str: an empty --out must not become Path("."), the working folder
        None, "--out", help="Published layer (default: <shot>.publish.vNNN.<format> beside the fills)."
    ),
    out_dir: Path = typer.Option(None, "--out-dir", help=OUT_DIR_HELP),
    tracker: str = typer.Option(
        None,
        "--tracker",
        help="Also send the approved take's MP4 and note to this tracker: kitsu (TWEEN_KITSU_* settings).",
    ),
    tracker_map: Path = typer.Option(None, "--tracker-map", help=TRACKER_MAP_HELP),
):
    """Dailies: write the approved take as a plain animation layer over the shot (no variants)."""
    from pipeline.usd.dailies import AlreadyPublished
    from pipeline.usd.dailies import publish as publish_take

    # The tracker's settings, the mapping and what it is sent (the approved take's MP4) are
    # checked before anything is written: a layer published for a take that cannot be sent
    # was refused by the next try ("already exists").
    sink, mapping = _tracker(tracker, tracker_map)
    approved = None if sink is None else _approved(shot, out_dir, mapping)
    try:
        r = publish_take(str(shot), fmt=fmt, dest=out, out_dir=str(out_dir) if out_dir else None)
    except AlreadyPublished as e:
        if sink is None:
            raise
        # Published by an earlier try whose send failed (the tracker was down): send it now.
        print(f"tween: {e.path}: published already; sending its take", file=sys.stderr)
    else:
        print(f"tween: published take {r['take']} of {r['of']}", file=sys.stderr)
        typer.echo(r["layer"])
    if sink is not None:
        sent = send_take(sink, approved)
        print(f"tween: sent take {sent['take']} to {sent['tracker']}: {sent['sequence']}/{sent['shot']}"
              f", status {sent.get('status')}", file=sys.stderr)  # fmt: skip


def _approved(shot: Path, out_dir: Path | None, mapping: dict | None):
    """The approved take of ``shot``'s latest fill with its MP4 (in ``review/`` beside the
    fills, where the farm renders it), as a tracker is sent it; one line saying what is
    missing."""
    from pipeline.usd.write import default_out_dir, shot_stem

    folder = Path(out_dir) if out_dir else default_out_dir(str(shot))
    try:
        return approved_of([folder.resolve()], f"0/{shot_stem(str(shot))}", mapping)
    except LookupError:
        raise TweenError(f"{shot}: no fill of it in {folder}") from None


def register(app: typer.Typer) -> None:
    """Adds this package's commands to ``app``."""
    app.command("dailies")(dailies)
    app.command("approve")(approve)
    app.command("publish")(publish)
