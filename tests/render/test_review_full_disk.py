"""A review's contact sheet and timeline on a full disk: OIIO's PNG writer and OTIO's
``write_to_file`` said nothing when the disk filled, and a truncated contact sheet and an
empty timeline were the review's output, with exit 0 (over an earlier good review's).

The disk is filled by a file-size limit (``RLIMIT_FSIZE``: writes past it fail with EFBIG, as
on a full disk with ENOSPC) in a child process, so no mount is needed."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

CHILD = """
import json, resource, signal, sys
from pathlib import Path
import numpy as np
from render.gl import RenderError
from render.output import contact_sheet
from render.timeline import take_track, update_timeline

signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # the write fails with EFBIG instead
out = Path(sys.argv[2])
noise = (np.random.default_rng(0).random((90, 160, 3)) * 255).astype(np.uint8)  # compresses badly
resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv[3]), resource.RLIM_INFINITY))
try:
    if sys.argv[1] == "sheet":
        contact_sheet([(noise, "1001", True)] * 8, str(out / "s_contact.png"), "sh010")
    else:
        facts = {"model": "interp", "model_hash": "0" * 12}
        track = take_track("s_take0.mp4", 24, range(1001, 1031), [1001, 1030], "take0", facts)
        update_timeline(None, out / "s.otio", "sh010", track, facts)
except RenderError as e:
    print(json.dumps({"error": str(e)}))
else:
    print(json.dumps({"error": None}))
"""


@pytest.mark.parametrize("what, limit", [("sheet", 16_384), ("timeline", 512)])
def test_a_full_disk_is_an_error_and_leaves_nothing(tmp_path, what, limit):
    r = subprocess.run([sys.executable, "-c", textwrap.dedent(CHILD), what, str(tmp_path), str(limit)],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 0, r.stderr
    error = json.loads(r.stdout.strip().splitlines()[-1])["error"]
    name = "s_contact.png" if what == "sheet" else "s.otio"
    assert error is not None and name in error and "File too large" in error
    assert list(tmp_path.iterdir()) == []  # no truncated file, no temporary


@pytest.mark.parametrize("what", ["sheet", "timeline"])
def test_with_room_both_are_written_whole(tmp_path, what):
    import OpenImageIO as oiio
    import opentimelineio as otio

    r = subprocess.run([sys.executable, "-c", textwrap.dedent(CHILD), what, str(tmp_path), str(1 << 30)],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert json.loads(r.stdout.strip().splitlines()[-1])["error"] is None, r.stderr
    if what == "sheet":
        buf = oiio.ImageBuf(str(tmp_path / "s_contact.png"))
        assert buf.read() and not buf.has_error and buf.spec().get_string_attribute("tween:shot") == "sh010"
        assert buf.spec().nchannels == 3 and buf.spec().width > 4 * 160
    else:
        tl = otio.adapters.read_from_file(str(tmp_path / "s.otio"))
        assert [t.name for t in tl.tracks] == ["take0"]
