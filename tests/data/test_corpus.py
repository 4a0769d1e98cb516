"""A corpus of several sources on different rigs (issue 30, item 1): read through the fill's
retargeting at the model's rate, cached compactly with a manifest, resumed after an
interruption, a bad file one line; training windows drawn by source weight."""

from __future__ import annotations

import fcntl
import gzip
import json
import pickle
import shutil
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from usd_fixtures import cmu_shot

from pipeline.data.cache import ClipSet
from pipeline.data.corpus import MANIFEST, CorpusError, load_corpus, open_corpus, prepare
from pipeline.train.batches import sample_batch
from pipeline.train.corpus import read_clip
from pipeline.usd.take import model_take, studio_take, take_files

BANDAI = (
    "dataset-2_walk_active_001.bvh.gz",
    "dataset-2_walk_active_002.bvh.gz",
    "dataset-2_run_active_001.bvh.gz",
)
CMU = "002_02.bvh.gz"  # the 100-joint Character Creator rig at 60 fps


@pytest.fixture(scope="module")
def sources(data_dir, tmp_path_factory):
    """Two sources on different rigs: Bandai BVH (one of them an eval clip the split drops), and
    a studio's Character Creator takes as BVH (60 fps) and as a Z-up USD shot."""
    root = tmp_path_factory.mktemp("sources")
    (root / "bandai").mkdir()
    for name in BANDAI:
        shutil.copy(data_dir / "bandai_namco" / "dataset-2" / name, root / "bandai" / name)
    (root / "studio").mkdir()
    shutil.copy(data_dir / "cmu_iclone" / CMU, root / "studio" / CMU)
    cmu_shot(root / "studio" / "sh010.usda", frames=121, keys_every=12)
    return root


def _describe(root, weights=(3.0, 1.0), extra="") -> str:
    text = f"""name = "two-rigs"
[[source]]
name = "bandai"
path = "bandai"
split = "train"
licence = "CC BY-NC 4.0"
weight = {weights[0]}
[[source]]
name = "studio"
path = "studio"
licence = "studio-internal"
weight = {weights[1]}
{extra}"""
    path = root / "corpus.toml"
    path.write_text(text)
    return path


def _prepare(root, out, **kw):
    return prepare(load_corpus(_describe(root)), out, read_clip, take_files, progress=False, **kw)


def test_two_rigs_go_the_fills_way_into_a_manifest_of_clips_frames_and_hours(sources, tmp_path):
    m = _prepare(sources, tmp_path / "c")
    assert json.loads((tmp_path / "c" / MANIFEST).read_text()) == m and m["complete"]
    bandai, studio = m["sources"]
    want_b = [studio_take(sources / "bandai" / n) for n in sorted(BANDAI) if "walk_active_002" not in n]
    want_s = [model_take(sources / "studio" / CMU), model_take(sources / "studio" / "sh010.usda")]
    assert (bandai["clips"], studio["clips"]) == (2, 2)  # the eval clip is not in the train split
    assert bandai["frames"] == sum(len(w) for w in want_b) and studio["frames"] == sum(len(w) for w in want_s)
    assert m["frames"] == bandai["frames"] + studio["frames"] and m["clips"] == 4
    assert m["hours"] == pytest.approx(m["frames"] / 30 / 3600, abs=1e-4)
    assert bandai["hours"] == pytest.approx(bandai["frames"] / 30 / 3600, abs=1e-4)
    assert (bandai["licence"], studio["licence"], bandai["weight"], studio["weight"]) == (
        "CC BY-NC 4.0", "studio-internal", 3.0, 1.0)  # fmt: skip
    # 180 bytes a frame: int16 quaternions and float32 roots.
    size = sum(f.stat().st_size for f in (tmp_path / "c").rglob("*.bin"))
    assert size == m["frames"] * (21 * 4 * 2 + 3 * 4)
    # Every clip comes back on the model skeleton at 30 fps, within the int16 quantisation.
    cs = open_corpus(tmp_path / "c")
    assert cs.fps == 30.0 and len(cs) == 4 and cs.names[0].startswith("bandai/")
    for i, want in enumerate(want_b + want_s):
        rot, root = cs.clip(i)
        q = want.rotations.astype(np.float64)
        q = q / np.linalg.norm(q, axis=-1, keepdims=True)
        assert np.abs(rot - q).max() < 1e-4
        np.testing.assert_allclose(root, want.root_positions, atol=1e-3)


def test_an_interrupted_prepare_resumes_and_ends_as_a_fresh_one(sources, tmp_path, capsys):
    fresh = tmp_path / "fresh"
    _prepare(sources, fresh)
    out, read = tmp_path / "c", []

    def dies_on_the_third(path, src, fps):
        if len(read) == 2:
            raise KeyboardInterrupt
        read.append(path.name)
        return read_clip(path, src, fps)

    with pytest.raises(KeyboardInterrupt):
        prepare(
            load_corpus(_describe(sources)), out, dies_on_the_third, take_files, progress=False, commit_s=0
        )
    assert not json.loads((out / MANIFEST).read_text())["complete"]
    with open(out / "bandai" / "rotations.bin", "ab") as f:  # half a clip past the last commit
        f.write(b"\x01" * 1000)
    with pytest.raises(CorpusError, match="prepare it again"):
        open_corpus(out)
    again = []

    def counted(path, src, fps):
        again.append(path.name)
        return read_clip(path, src, fps)

    m = prepare(load_corpus(_describe(sources)), out, counted, take_files, progress=False)
    assert not set(again) & set(read) and len(again) == 2  # only what was not committed
    assert m["sources"] == json.loads((fresh / MANIFEST).read_text())["sources"]
    for f in ("bandai/rotations.bin", "bandai/roots.bin", "studio/rotations.bin", "studio/roots.bin"):
        assert (out / f).read_bytes() == (fresh / f).read_bytes()
    # A second prepare of the same folder while one runs waits for it, says so, then reads nothing.
    held = open(out / ".lock", "w")
    fcntl.flock(held, fcntl.LOCK_EX)
    threading.Timer(1.0, held.close).start()  # the other process finishes after a second
    t0 = time.monotonic()
    waited = prepare(load_corpus(_describe(sources)), out, lambda *a: pytest.fail("read again"), take_files,
                     progress=False)  # fmt: skip
    assert time.monotonic() - t0 >= 0.9 and waited == m
    assert "being prepared by another process; waiting for it" in capsys.readouterr().err
    # Prepared, it reads nothing again.
    m2 = prepare(load_corpus(_describe(sources)), out, lambda *a: pytest.fail("read again"), take_files,
                 progress=False)  # fmt: skip
    assert m2 == m


def test_a_bad_file_is_one_line_naming_it_and_the_others_go_on(sources, tmp_path, capsys):
    src = tmp_path / "src"
    shutil.copytree(sources, src)
    bad = src / "studio" / "broken.bvh.gz"
    with gzip.open(bad, "wt") as f:
        f.write("HIERARCHY\nROOT Hips\n{\n")
    m = prepare(load_corpus(_describe(src)), tmp_path / "c", read_clip, take_files, progress=False)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tween: skipped clip: ") and str(bad) in err[0]
    studio = m["sources"][1]
    assert studio["clips"] == 2 and [f["file"] for f in studio["failed"]] == [str(bad)]


def test_windows_are_drawn_by_source_weight_and_unweighted_sets_draw_as_before(sources, tmp_path):
    _prepare(sources, tmp_path / "c")
    cs = open_corpus(tmp_path / "c", load_corpus(_describe(sources, weights=(1.0, 3.0))))
    rng, where = np.random.default_rng(0), []
    for _ in range(100):
        sample_batch(cs, rng, 32, 64, where)
    share = np.mean([cs.names[c].startswith("studio/") for c, _ in where])
    assert abs(share - 0.75) < 0.03
    # Batch-making processes (--workers) get the files' names, not the frames.
    blob = pickle.dumps(cs)
    assert len(blob) < 20_000 and np.array_equal(pickle.loads(blob).clip(3)[0], cs.clip(3)[0])
    # Without weights (the train split, --data) the draws are those of before, bit for bit.
    plain = ClipSet(cs.names, cs.starts, cs.lengths, np.random.rand(int(cs.lengths.sum()), 21, 4),
                    np.random.rand(int(cs.lengths.sum()), 3), 30.0)  # fmt: skip
    a, b = np.random.default_rng(5), np.random.default_rng(5)
    ok = np.flatnonzero(plain.lengths >= 64)
    pick = b.choice(ok, size=8)
    where = []
    sample_batch(plain, a, 8, 64, where)
    assert [c for c, _ in where] == list(pick)


@pytest.mark.parametrize(
    "extra, says",
    [
        ('colour = "red"', "unknown key(s) ['colour']"),
        ("weight = -1", "'weight' must be a positive number"),
        ('split = "eval"', "'split' is \"train\" or absent"),
    ],
)
def test_a_bad_description_is_one_line_naming_the_file(sources, tmp_path, extra, says):
    d = tmp_path / "d"
    shutil.copytree(sources, d)
    path = _describe(d)
    text = path.read_text().replace("weight = 1.0\n", "") + '[[source]]\nname = "x"\npath = "studio"\n'
    path.write_text(text + 'licence = "CC0"\n' + extra + "\n")
    with pytest.raises(CorpusError, match=str(path).replace(".", r"\.")) as e:
        load_corpus(path)
    assert says in str(e.value) and "\n" not in str(e.value)
    r = subprocess.run(
        [sys.executable, "-m", "pipeline.train.corpus", str(path)], capture_output=True, text=True
    )
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and r.stderr.startswith("tween: error: ")


def test_a_corpus_trains_alone(sources, tmp_path):
    from pipeline.train.generator_training import TrainConfig

    with pytest.raises(ValueError, match="--corpus .*: reads its own sources; drop --data"):
        TrainConfig(corpus="c.toml", data="takes")
