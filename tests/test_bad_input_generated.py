"""Every command against generated bad input (Hypothesis): wrong types, out-of-range values,
missing, empty, garbled and wrong-format files, duplicate JSON keys, existing destinations.

Each example must keep the contract of ``cli_contract.refused``: one ``tween: error:`` line,
exit status 2, nothing written or changed anywhere (the user's files included), and only
options the command takes named in the line. ``TWEEN_HYPOTHESIS_EXAMPLES`` sets the examples
per command (``make test-nightly`` runs many more than ``make test``).
"""

from __future__ import annotations

import gzip
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import pytest
from cli_contract import refused
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = int(os.environ.get("TWEEN_HYPOTHESIS_EXAMPLES", "200"))


@dataclass(frozen=True)
class Assets:
    """Good inputs the cases start from (a shot, a BVH take, a finished model), in one folder
    the contract watches: a refused command must leave them exactly as they were."""

    root: Path
    shot: Path
    bvh: Path
    model: Path


@pytest.fixture(scope="module")
def assets(tmp_path_factory, bandai_clip) -> Assets:
    root = tmp_path_factory.mktemp("assets")
    shutil.copy(ROOT / "examples" / "sh010_walk.usda", root / "sh010.usda")
    (root / "take.bvh").write_bytes(gzip.decompress(bandai_clip.read_bytes()))
    (root / "model").mkdir()
    shutil.copy(ROOT / "models" / "default" / "model.json", root / "model" / "model.json")
    return Assets(root, root / "sh010.usda", root / "take.bvh", root / "model")


# ------------------------------------------------------------------------- bad values

words = st.text(st.characters(codec="utf-8", exclude_categories=("Cs", "Cc")), min_size=1, max_size=12)
# Text that is no number at all (``nan`` and ``inf`` parse as floats: they come separately).
not_number = words.filter(lambda s: not _parses(s))
negative = st.integers(max_value=-1).map(str)
non_finite = st.sampled_from(["nan", "inf", "-inf", "NaN"])


def _parses(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


@st.composite
def bad_file(draw, folder: Path, suffix: str, good: Path | None = None) -> Path:
    """A path with ``suffix`` that is no readable file of its kind: missing, a folder, empty,
    random bytes or text, or a good file cut short."""
    kinds = ["missing", "folder", "empty", "bytes", "text"] + (["cut"] if good else [])
    kind = draw(st.sampled_from(kinds))
    p = folder / f"input{suffix}"
    if kind == "folder":
        p.mkdir()
    elif kind == "empty":
        p.write_bytes(b"")
    elif kind == "bytes":
        p.write_bytes(draw(st.binary(min_size=1, max_size=300)))
    elif kind == "text":
        p.write_text(draw(st.text(min_size=1, max_size=300)))
    elif kind == "cut":
        data = good.read_bytes()
        p.write_bytes(data[: draw(st.integers(1, min(len(data) - 1, 4000)))])
    return p


@st.composite
def bad_json(draw, folder: Path) -> Path:
    """A mapping file a person got wrong: a key twice, not an object, not JSON, not a string."""
    p = folder / "mapping.json"
    joint = draw(st.sampled_from(["Hips", "Head", "Foot_L"]))
    p.write_text(
        draw(
            st.sampled_from(
                [
                    f'{{"{joint}": "a", "{joint}": "b"}}',
                    "[1, 2, 3]",
                    '{"Hips": ',
                    f'{{"{joint}": 3}}',
                    '"just a string"',
                ]
            )
        )
    )
    return p


# ------------------------------------------------------------------------------ cases
# Each case draws one bad input (the rest of the command line good) and returns the argv.


def convert_case(draw, ws: Path, a: Assets):
    out = ws / "shot.usda"
    which = draw(st.sampled_from(["source", "fps", "keys", "start", "up", "frames", "exists"]))
    if which == "source":
        return ["convert", draw(bad_file(ws, ".bvh", a.bvh)), out]
    if which == "exists":
        out.write_text("#usda 1.0\n")
        return ["convert", a.bvh, out]
    value = {
        "fps": st.one_of(not_number, non_finite, st.sampled_from(["0", "-24"])),
        "keys": st.one_of(not_number, negative, st.just("0")),
        "start": st.one_of(not_number, non_finite),
        "up": words.filter(lambda s: s.lower() not in ("y", "z")),
        "frames": st.sampled_from(["abc", "10-5", "-", "5-5", "999999-1000000", "1:2:3"]),
    }[which]
    flag = {"fps": "--fps", "keys": "--keys-every", "start": "--start", "up": "--up", "frames": "--frames"}
    return ["convert", a.bvh, out, flag[which], draw(value)]


def fill_case(draw, ws: Path, a: Assets):
    # `tween fill` and `submit` check all this before a farm starts or a broker is contacted.
    cmd = draw(st.sampled_from(["fill-local", "fill", "submit"]))
    which = draw(
        st.sampled_from(["shot", "range", "takes", "seed", "mapping", "model", "trust", "keys", "out"])
    )
    if which == "shot":
        return [cmd, draw(bad_file(ws, draw(st.sampled_from([".usda", ".usd", ".bvh"])), a.shot))]
    if which == "mapping":
        return [cmd, a.shot, "--mapping", draw(st.one_of(bad_json(ws), bad_file(ws, ".json")))]
    if which == "out":  # a read-only folder (mode bits: refused even for root)
        ro = ws / "published"
        ro.mkdir()
        ro.chmod(0o555)
        return [cmd, a.shot, "--out", ro / "fills"]
    value = {
        "range": st.sampled_from(["abc", "20:10", "1:", ":", "99999:100000", "1001:1001:1"]),
        "takes": st.one_of(not_number, negative, st.sampled_from(["0", "65", "1.5"])),
        "seed": st.one_of(not_number, negative),
        "model": st.from_regex(r"[a-z]{3,10}-nosuch", fullmatch=True),
        "trust": words.filter(lambda s: s not in ("auto", "model", "spline", "off", "on")),
        "keys": st.sampled_from(["abc", "1001,abc", "-5", "1001,1001", "999999"]),
    }[which]
    return [cmd, a.shot, f"--{which}", draw(value)]


def dailies_case(draw, ws: Path, a: Assets):
    cmd = draw(st.sampled_from(["approve", "publish", "review"]))
    shot = draw(bad_file(ws, ".usda", a.shot))
    extra = {"approve": ["--take", "0"], "publish": [], "review": ["-o", ws / "review"]}[cmd]
    if draw(st.booleans()):  # a good shot and a bad option instead
        shot = a.shot
        extra = {
            "approve": ["--take", draw(st.one_of(negative, not_number))],
            "publish": ["--format", draw(words.filter(lambda s: s not in ("usda", "usdc", "usd")))],
            "review": [
                "--size",
                draw(st.one_of(not_number, st.sampled_from(["0x0", "-5x10", "99999x99999"]))),
            ],
        }[cmd]
    return [cmd, shot, *extra]


def train_case(draw, ws: Path, a: Assets):
    from pipeline.train.generator_training import _RANGES

    out = ws / "run"
    if draw(st.integers(0, 3)) == 0:  # refused before the path predictor's default 2000 steps
        from test_pack_damaged import tiny_clips

        from pipeline.data.pack import pack

        good = pack(tiny_clips(), ws / "good.pack")
        return ["train", "--out", out, "--data-pack", draw(bad_file(ws, ".pack", good))]
    if draw(st.booleans()):
        takes = ws / "takes"
        takes.mkdir()
        draw(bad_file(takes, ".bvh", a.bvh)) if draw(st.booleans()) else None
        return ["train", "--out", out, "--data", takes, "--steps", "4", "--path-steps", "0"]
    name = draw(st.sampled_from(sorted(_RANGES)))
    lo, hi = _RANGES[name]
    whole = name in ("steps", "batch", "gap_start", "gap_end", "seed", "threads", "limit_clips", "dna_max",
                     "workers", "lengths", "adv_start")  # fmt: skip
    below = st.integers(max_value=int(lo) - 1) if whole else st.floats(max_value=lo, exclude_max=True)
    if name == "adv_start":  # negative means "none", past --steps "not in this run" (documented)
        below = above = st.nothing()
    else:
        above = st.integers(min_value=int(hi) + 1) if whole else st.floats(min_value=hi, exclude_min=True)
    bad = draw(st.one_of(below, above, non_finite if not whole else st.nothing(), not_number))
    return [
        "train",
        "--out",
        out,
        "--steps",
        "8",
        "--" + name.replace("_", "-"),
        bad,
    ]  # (the last one counts)


def train_rig_case(draw, ws: Path, a: Assets):
    out = ws / "rig"
    which = draw(
        st.sampled_from(["source", "schedule", "iters", "frames", "device", "fps", "ratio", "model"])
    )
    if which == "source":
        src = draw(bad_file(ws, draw(st.sampled_from([".bvh", ".usda", ".npz"])), a.bvh))
        return ["train-rig", src, "--out", out, "--schedule", "tiny"]
    if which == "model":  # a finished model in --out
        return ["train-rig", a.bvh, "--out", a.model, "--schedule", "tiny"]
    value = {
        "schedule": words.filter(lambda s: s not in ("tiny", "reduced", "paper")),
        "iters": st.one_of(negative, st.just("0"), not_number),
        "frames": st.sampled_from(["abc", "10:5", "5:5", "-3:2", "1:2:3"]),
        "device": words.filter(lambda s: not s.startswith(("cpu", "cuda"))),
        "fps": st.one_of(not_number, non_finite, st.sampled_from(["0", "-30"])),
        "ratio": st.one_of(not_number, non_finite, st.sampled_from(["0", "-0.5", "1.5"])),
    }[which]
    return ["train-rig", a.bvh, "--out", out, "--schedule", "tiny", f"--{which}", draw(value)]


def library_case(draw, ws: Path, a: Assets):
    which = draw(st.sampled_from(["folder", "takes", "out", "info"]))
    if which == "info":
        lib = ws / "lib"
        lib.mkdir()
        manifest = draw(st.sampled_from(['{"takes": [], "takes": []}', "[]", "{", '{"format": 99}']))
        if draw(st.booleans()):
            (lib / "library.json").write_text(manifest)
        return ["library", "info", lib]
    if which == "folder":
        return ["library", "build", draw(bad_file(ws, "")), "--out", ws / "lib"]
    if which == "out":  # a folder that is not a library, or a file
        out = ws / "lib"
        if draw(st.booleans()):
            out.mkdir()
            (out / "notes.txt").write_text("mine")
        else:
            out.write_text("mine")
        return ["library", "build", a.root, "--out", out]
    takes = ws / "takes"  # nothing readable in it
    takes.mkdir()
    draw(bad_file(takes, ".bvh", a.bvh))
    return ["library", "build", takes, "--out", ws / "lib"]


def export_case(draw, ws: Path, a: Assets):
    run = ws / "run"
    run.mkdir()
    which = draw(st.sampled_from(["checkpoint", "pad", "root", "min-window", "model"]))
    (run / "generator.pt").write_bytes(draw(st.binary(max_size=64)))  # not a checkpoint
    if which == "checkpoint":
        return ["export", run, "--out", ws / "model"]
    if which == "model":
        return ["export", run, "--out", a.model]
    value = {
        "pad": words.filter(lambda s: s not in ("hold-key", "end", "front")),
        "root": words.filter(lambda s: s not in ("generator", "path")),
        "min-window": st.one_of(negative, not_number),
    }[which]
    return ["export", run, "--out", ws / "model", f"--{which}", draw(value)]


def farm_and_page_case(draw, ws: Path, a: Assets):
    """``rig-extract``, ``cancel`` and ``status`` of unknown jobs, and ``dailies`` (never a
    value that would start its server)."""
    cmd = draw(st.sampled_from(["rig-extract", "cancel", "status", "dailies"]))
    if cmd == "rig-extract":
        if draw(st.booleans()):
            return [cmd, draw(bad_file(ws, draw(st.sampled_from([".bvh", ".usda"])), a.bvh)), ws / "clip.npz"]
        return [
            cmd,
            a.bvh,
            ws / "clip.npz",
            "--frames",
            draw(st.sampled_from(["abc", "10:5", "5:5", "1:2:3"])),
        ]
    if cmd in ("cancel", "status"):
        return [cmd, draw(st.from_regex(r"[a-z0-9][a-z0-9-]{0,19}", fullmatch=True))]  # (not an option)
    if draw(st.booleans()):  # no such folder, or a file: never a folder it would serve
        root = ws / "shots"
        if draw(st.booleans()):
            root.write_bytes(draw(st.binary(max_size=50)))
        return [cmd, root, "--port", "0"]
    port = draw(st.one_of(st.integers(max_value=-1), st.integers(min_value=65536)).map(str) | not_number)
    return [cmd, ws, "--port", port]


def bench_case(draw, ws: Path, a: Assets):
    """``tween bench`` refuses before it reads any data (never a value that would run it)."""
    which = draw(st.sampled_from(["methods", "limit", "posture"]))
    value = {
        "methods": st.from_regex(r"[a-z]{2,8}-nosuch(,interp)?", fullmatch=True),
        "limit": st.integers(max_value=0).map(str),
        "posture": st.one_of(
            st.floats(max_value=0, exclude_max=True), st.floats(min_value=180, exclude_min=True), non_finite
        ).map(str),
    }[which]
    return ["bench", "--out", ws / "bench", f"--{which}", draw(value)]


CASES = {
    "convert": convert_case,
    "fill-local/fill/submit": fill_case,
    "approve/publish/review": dailies_case,
    "train": train_case,
    "train-rig": train_rig_case,
    "library": library_case,
    "export": export_case,
    "rig-extract/cancel/status/dailies": farm_and_page_case,
    "bench": bench_case,
}


@pytest.mark.parametrize("name", list(CASES))
def test_generated_bad_input_is_refused_in_one_line_and_writes_nothing(name, assets, capsys, monkeypatch):
    if name in ("train", "train-rig", "export"):
        pytest.importorskip("torch")
    monkeypatch.setenv("TWEEN_FARM_CONFIG", os.devnull)
    case = CASES[name]

    @settings(max_examples=EXAMPLES, deadline=None, database=None,
              suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])  # fmt: skip
    @given(st.data())
    def check(data):
        with tempfile.TemporaryDirectory() as d:
            ws = Path(d)
            argv = case(data.draw, ws, assets)
            try:
                refused(argv, capsys, ws, assets.root)
            finally:
                for p in ws.rglob("*"):  # a read-only folder the case made must go again
                    if p.is_dir():
                        p.chmod(0o755)

    check()
