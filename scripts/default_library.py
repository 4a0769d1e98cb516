"""The library the default model ships beside its network (``models/default/library``): the
CMU takes of subjects 1, 2 and 3 (about 3 minutes, three actors), on the model skeleton.

Other actors' motion is what the network was never trained on; a library of another lab's
capture filled CMU subjects 5-7 at 0.905 / 0.922 x the spline (keys every 10 / 30) against the
network's 1.007 / 0.967 (docs/models.md). The subjects the benches hold out (5, 6, 7) are not
in it. The CMU database's terms allow any use, so the library adds no restriction to the
model's own licence. Each take's ``file`` is recorded relative to the shared data folder
(``cmu_iclone/001_01.bvh.gz``), not as this machine's path; the library's hash is over the
takes' contents and does not change with it.

``python scripts/default_library.py [--out models/default/library]``
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

from pipeline.bench.heldout import cmu_files
from pipeline.data.split import shared_data_dir
from pipeline.library.build import build
from pipeline.library.store import open_library

OUT = Path(__file__).resolve().parents[1] / "models" / "default" / "library"
SUBJECTS = (1, 2, 3)
LICENCE = "CMU Graphics Lab Motion Capture Database terms (mocap.cs.cmu.edu): free for all uses, commercial products included, but not to be resold as data, even converted; credit the lab"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args(argv)
    if a.out.exists():
        shutil.rmtree(a.out)
    root = shared_data_dir().resolve()
    res = build(None, a.out, files=cmu_files(SUBJECTS), licence=LICENCE, name="cmu-subjects-1-3")
    path = a.out / "library.json"
    manifest = json.loads(path.read_text())
    for take in manifest["takes"]:
        take["file"] = Path(take["file"]).resolve().relative_to(root).as_posix()
    path.write_text(json.dumps(manifest, indent=1) + "\n")
    lib = open_library(a.out)
    assert lib.hash == res["hash"]
    print(
        f"{a.out}: {res['takes']} takes, {res['frames']} frames ({res['hours'] * 60:.1f} min), hash {lib.hash}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
