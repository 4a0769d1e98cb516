"""Training data plumbing: the packed split, batches made by worker processes, gap weights."""

import numpy as np
import torch

from pipeline.data.cache import load_split
from pipeline.data.pack import load_pack, pack
from pipeline.data.skeletons import FOOT_JOINTS, bandai_skeleton
from pipeline.networks.generator import GeneratorConfig
from pipeline.train.generator_training import TrainConfig, batches_from, step_batch


def test_pack_round_trip_is_within_quantisation(tmp_path):
    clips = load_split("train", limit=30)
    out = load_pack(pack(clips, tmp_path / "train.pack"))
    assert out.names == clips.names and np.array_equal(out.lengths, clips.lengths)
    assert np.array_equal(out.starts, clips.starts) and out.fps == clips.fps
    assert np.abs(out.rotations - clips.rotations).max() < 2.5e-4  # 1/4096 steps, renormalised
    assert np.abs(out.roots - clips.roots).max() <= 0.0051  # 1/100 cm
    assert (tmp_path / "train.pack").stat().st_size < clips.rotations.nbytes / 3


def _cfg(**kw):
    return TrainConfig(
        steps=4,
        batch=4,
        lengths=(64,),
        limit_clips=30,
        model=GeneratorConfig(width=48, levels=(48, 64, 64)),
        **kw,
    )


def test_worker_batches_equal_in_process_batches():
    clips = load_split("train", limit=30)
    skel = bandai_skeleton()
    feet = [skel.index(n) for n in FOOT_JOINTS]
    here = list(batches_from(_cfg(), clips, skel, feet, 1))
    there = list(batches_from(_cfg(workers=2), clips, skel, feet, 1))
    assert len(here) == len(there) == 3
    for a, b in zip(here, there, strict=True):
        for k in ("feats", "gpos", "keys", "frame_weight"):
            assert torch.equal(a[k], b[k]), k


def test_gap_weighting_evens_out_gaps():
    clips = load_split("train", limit=30)
    skel = bandai_skeleton()
    feet = [skel.index(n) for n in FOOT_JOINTS]
    for step in range(20):
        flat = step_batch(_cfg(), clips, skel, feet, step)
        even = step_batch(_cfg(gap_weighting=1.0), clips, skel, feet, step)
        if flat is None:
            continue
        assert torch.equal(flat["feats"], even["feats"])  # weighting changes the loss only
        m = flat["between"].numpy()
        assert np.allclose(flat["frame_weight"].numpy()[m], 1.0)
        keys = flat["keys"].numpy()
        w = even["frame_weight"].numpy()
        # With α = 1 a frame weighs 1 / its gap's length (times one normalising constant).
        per_gap = [w[a + 1 : b] * (b - a) for a, b in zip(keys[:-1], keys[1:], strict=True) if b - a > 1]
        assert np.allclose(np.concatenate(per_gap), per_gap[0][0], rtol=1e-5)


def test_the_pack_entry_point_answers_help_and_writes_nothing_else(tmp_path):
    """``python -m pipeline.data.pack --help`` is its help (it once packed the split into a
    file named --help), and an output path through a file is one line naming it, exit 2."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "pipeline.data.pack", "--help"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 0 and r.stdout.startswith("usage: python -m pipeline.data.pack")
    assert list(tmp_path.iterdir()) == []
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    r = subprocess.run([sys.executable, "-m", "pipeline.data.pack", str(blocker / "train.npz")],
                       capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 2 and r.stderr.count("tween: error:") == 1 and "Traceback" not in r.stderr, (
        r.stderr
    )
    assert str(blocker) in r.stderr and blocker.read_text() == "not a folder"
