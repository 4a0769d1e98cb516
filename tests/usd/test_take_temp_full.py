"""A BVH take (a --dna take, a corpus's, a bench's) is converted to a USD take in the system
temp folder first; with that folder full, the error named the converted file in a folder of a
random name under TMPDIR ("/tmp/tmpk2x…/take.usda: file too large"), gone by then. It names the
system temp folder and says it is full, and leaves nothing there. The disk is filled by a
file-size limit (RLIMIT_FSIZE) in a child process, as the project's other full-disk tests do."""

import os
import subprocess
import sys

from usd_fixtures import BANDAI_CLIP

CHILD = """
import resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))
from pipeline.errors import TweenError
from pipeline.usd.take import model_take
try:
    model_take(sys.argv[1])
except TweenError as e:
    print(e)
"""


def test_a_take_converted_in_a_full_system_temp_folder_names_the_folder(tmp_path):
    systmp = tmp_path / "systmp"
    systmp.mkdir()
    env = {**os.environ, "TMPDIR": str(systmp), "TWEEN_CACHE": str(tmp_path / "cache")}
    res = subprocess.run([sys.executable, "-c", CHILD, str(BANDAI_CLIP)], env=env, capture_output=True, text=True,
                         timeout=60)  # fmt: skip
    assert res.returncode == 0 and res.stderr == "", res.stderr[-3000:]
    assert res.stdout == (
        f"{systmp}: the system temp folder is full (file too large) while converting the take {BANDAI_CLIP}; "
        "free space there, or set TMPDIR to a folder with room, and run again\n"
    )
    assert list(systmp.iterdir()) == []
