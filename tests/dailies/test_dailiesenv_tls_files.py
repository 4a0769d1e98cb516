"""`tween dailies --certfile/--keyfile` naming what is not a certificate file: a pipe (which
would hold the TLS load for ever) is said to be not a regular file, not "no such file"; one
line, exit 2, nothing served."""

import os
import subprocess
import sys

import pytest

TWEEN = [sys.executable, "-m", "pipeline.cli", "dailies"]


def _one_error(tmp_path, *args) -> str:
    r = subprocess.run([*TWEEN, str(tmp_path), *map(str, args)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and r.stdout == "", (r.stdout, r.stderr)
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("tween: error: "), r.stderr
    return lines[0]


@pytest.mark.parametrize("opt", ["--certfile", "--keyfile"])
def test_a_pipe_as_the_certificate_or_its_key_is_not_a_regular_file(tmp_path, opt):
    pem = tmp_path / "other.pem"
    pem.write_text("not a certificate\n")
    fifo = tmp_path / "tls.pem"
    os.mkfifo(fifo)
    given = {"--certfile": pem, "--keyfile": pem, opt: fifo}
    line = _one_error(tmp_path, *[a for kv in given.items() for a in kv])
    kind = "TLS certificate" if opt == "--certfile" else "private key"
    assert f"{opt} {fifo}: not a regular file (a pipe, socket or device), not a {kind}" in line, line
    # What else is no certificate file is said as what it is too; a file not there as before.
    (tmp_path / "dangling.pem").symlink_to(tmp_path / "gone.pem")
    for path, why in ((tmp_path / "gone.pem", "no such file"), (tmp_path / "dangling.pem", "a link to nothing"),
                      (tmp_path, f"a folder, not a {kind}")):  # fmt: skip
        line = _one_error(tmp_path, *[a for kv in {**given, opt: path}.items() for a in kv])
        assert line.endswith(f"{opt} {path}: {why}"), line
