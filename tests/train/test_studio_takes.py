"""A studio's own takes for fine-tuning (`tween train --data FOLDER --init MODEL`): any
humanoid rig, BVH or USD, mapped and retargeted as the fill does; the network's shape from
the checkpoint it continues."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from pipeline.data.skeletons import bandai_skeleton
from pipeline.errors import ShotError, TweenError
from pipeline.motion.bvh import read_bvh
from pipeline.usd.take import load_takes, model_take, take_files

CMU_TAKE = "002_02.bvh.gz"  # a short walk on the 100-joint Character Creator rig, 60 fps (74 frames at 30)
SHORT_TAKE = "002_03.bvh.gz"  # 43 frames at 30 fps: shorter than any training window


@pytest.fixture
def takes(data_dir, bandai_clip, tmp_path):
    folder = tmp_path / "takes"
    (folder / "sub").mkdir(parents=True)
    shutil.copy(data_dir / "cmu_iclone" / CMU_TAKE, folder / "sub" / CMU_TAKE)
    shutil.copy(bandai_clip, folder / bandai_clip.name)
    (folder / "notes.txt").write_text("not a take")
    return folder


def test_takes_of_any_rig_come_on_the_model_skeleton_at_30_fps(takes, bandai_clip, monkeypatch, tmp_path):
    monkeypatch.setenv("TWEEN_CACHE", str(tmp_path / "cache"))
    files = take_files(takes)
    assert [f.name for f in files] == [bandai_clip.name, CMU_TAKE]  # recursive, takes only
    cs = load_takes(takes)
    assert cs.fps == 30.0 and cs.rotations.shape[1:] == (len(bandai_skeleton()), 4)
    # The model skeleton's own BVH is read exactly as the protocol reads it ...
    own = read_bvh(bandai_clip).continuous()
    rot, root = cs.clip(0)
    assert np.array_equal(rot, own.rotations) and np.array_equal(root, own.root_positions)
    # ... another rig goes the fill's way: 60 fps resampled to 30, retargeted onto the model.
    cmu = model_take(takes / "sub" / CMU_TAKE)
    src = read_bvh(takes / "sub" / CMU_TAKE)
    assert abs(len(cmu) - len(src) / 2) <= 1
    rot, root = cs.clip(1)
    np.testing.assert_allclose(rot, cmu.rotations, atol=1e-6)
    np.testing.assert_allclose(root, cmu.root_positions, atol=1e-4)
    # --limit-clips: the first N takes only (it was ignored with --data, every take trained on).
    one = load_takes(takes, limit=1)
    assert one.names == cs.names[:1] and np.array_equal(one.clip(0)[0], cs.clip(0)[0])
    # Cached: a second call reads no file; a changed take is read again.
    monkeypatch.setattr("pipeline.usd.take.model_take", lambda *a, **k: pytest.fail("read again"))
    again = load_takes(str(takes) + "/")
    assert np.array_equal(again.rotations, cs.rotations)
    assert len(load_takes(takes, include="dataset-*")) == 1  # another file set, its own cache


def test_include_picks_takes_by_name_and_bad_folders_are_named(takes, tmp_path):
    assert [f.name for f in take_files(takes, "00*, nothing*")] == [CMU_TAKE]
    with pytest.raises(ShotError, match="no BVH or USD takes matching"):
        take_files(takes, "999_*")
    with pytest.raises(ShotError, match="no such folder"):
        take_files(tmp_path / "missing")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ShotError, match=str(empty)):
        take_files(empty)


def test_takes_are_found_whatever_their_case_and_through_linked_folders(
    data_dir, bandai_clip, tmp_path, capsys
):
    """``WALK.BVH.GZ`` and a gzipped take named ``.bvh`` are BVH takes (before: the first was
    read as USD, the second "expected HIERARCHY"); a linked folder of takes is searched (once,
    even when linked twice or linked to a folder above); a link to nothing is said, not dropped."""
    shared = tmp_path / "shared"
    shared.mkdir()
    shutil.copy(data_dir / "cmu_iclone" / CMU_TAKE, shared / "WALK.BVH.GZ")
    folder = tmp_path / "takes"
    folder.mkdir()
    (folder / "gz_named_plain.bvh").write_bytes(bandai_clip.read_bytes())  # gzipped, named .bvh
    assert bandai_clip.read_bytes()[:2] == b"\x1f\x8b"
    (folder / "linked").symlink_to(shared, target_is_directory=True)
    (folder / "linked_again").symlink_to(shared, target_is_directory=True)
    (shared / "up").symlink_to(folder, target_is_directory=True)
    (folder / "gone.bvh").symlink_to(tmp_path / "nowhere.bvh")
    files = take_files(folder)
    assert sorted(f.name for f in files) == ["WALK.BVH.GZ", "gz_named_plain.bvh"], files
    assert f"tween: skipped take: {folder / 'gone.bvh'}: a link to nothing" in capsys.readouterr().err
    walk = model_take(next(f for f in files if f.name == "WALK.BVH.GZ"))
    assert walk.name == "WALK" and abs(len(walk) - len(read_bvh(data_dir / "cmu_iclone" / CMU_TAKE)) / 2) <= 1
    plain = read_bvh(folder / "gz_named_plain.bvh")
    assert plain.name == "gz_named_plain" and np.array_equal(plain.rotations, read_bvh(bandai_clip).rotations)


def test_a_take_that_is_no_motion_is_one_clear_error(tmp_path):
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n")
    with pytest.raises(TweenError, match="bad.bvh.*truncated"):
        load_takes(tmp_path)


def test_fine_tune_continues_a_model_folder_with_its_shape(takes, data_dir, tmp_path, monkeypatch, capsys):
    torch = pytest.importorskip("torch")
    from typer.testing import CliRunner

    from pipeline.cli import app
    from pipeline.infer.folder import RETIRED

    monkeypatch.setenv("TWEEN_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "run"
    opts = ["--path-steps", "0", "--steps", "6", "--batch", "4", "--lengths", "64", "--adv-start", "-1"]
    args = ["train", "--data", str(takes), "--data-include", "00*", "--init", "models/default", *opts]
    res = CliRunner().invoke(app, [*args, "--out", str(out)], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    base = torch.load("models/default/torch/generator.pt", weights_only=False)
    run = torch.load(out / "generator.pt", weights_only=False)
    saved, got = base["config"]["model"], run["config"]["model"]
    saved = {k: v for k, v in saved.items() if k not in RETIRED}  # (switches no release runs)
    assert {k: got[k] for k in saved} == saved and not got["delta"]  # the adapter came with it
    assert run["config"]["data_include"] == "00*" and run["step"] == 6
    moved = [k for k in base["model"] if not torch.equal(base["model"][k], run["model"][k])]
    assert moved and set(run["model"]) == set(base["model"])  # continued, every weight kept
    # Exported, it claims no familiar credit: its probes alone decide in the trusted fill.
    from pipeline.infer.generator_onnx import OnnxInbetweener
    from pipeline.train import export as ex

    monkeypatch.setattr(ex, "_pose_bank", lambda *a: None)  # (the train split is not read here)
    res = CliRunner().invoke(
        app, ["export", str(out), "--out", str(tmp_path / "model")], catch_exceptions=False
    )
    assert res.exit_code == 0, res.output
    meta = json.loads((tmp_path / "model" / "model.json").read_text())
    assert meta["familiar_credit"] is False
    # It keeps the terms of the model it continued (CC BY-NC 4.0) beside the studio's takes.
    assert "CC BY-NC 4.0" in meta["licence"] and "not stated" in meta["licence"]
    uses = [s["use"] for s in meta["sources"]]  # the run records its paths absolute
    assert (
        uses[0] == "trained" and uses[1] == f"inherited: initialised from {Path('models/default').absolute()}"
    )
    # A studio that measured its fine-tune ahead of the spline gives it the credit at export.
    res = CliRunner().invoke(app, ["export", str(out), "--out", str(tmp_path / "m2"), "--familiar-credit"],
                             catch_exceptions=False)  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "familiar_credit" not in json.loads((tmp_path / "m2" / "model.json").read_text())
    assert OnnxInbetweener(tmp_path / "model").capabilities.familiar_credit is False
    assert OnnxInbetweener("models/default").capabilities.familiar_credit is True
    # Takes too short for a training window, and a folder with no checkpoint: one line each.
    from pipeline.cli import main

    short = tmp_path / "short"
    short.mkdir()
    shutil.copy(data_dir / "cmu_iclone" / SHORT_TAKE, short / SHORT_TAKE)
    empty = tmp_path / "no_model"
    empty.mkdir()
    for argv, want in (
        (["train", "--data", str(short), *opts], "the longest is 43: give longer takes"),
        (["train", "--data", str(takes), "--init", str(empty), *opts], "holds no torch/generator.pt"),
    ):
        with pytest.raises(SystemExit) as ex:
            main([*argv, "--out", str(tmp_path / "r")])
        err = capsys.readouterr().err.strip().splitlines()
        assert ex.value.code == 2 and want in err[-1] and err[-1].startswith("tween: error: "), err
        assert not (tmp_path / "r" / "generator.pt").exists()


def test_a_fine_tune_exports_a_pose_bank_with_the_studio_takes(takes, tmp_path, monkeypatch):
    """The exported bank holds the train split's poses and, for a fine-tune on a studio's
    takes, as many of the takes' own (so its own characters count as familiar); a network
    with relative pose inputs gets none (docs/trust.md)."""
    pytest.importorskip("torch")
    from pipeline.data import posebank
    from pipeline.data.cache import load_split
    from pipeline.infer.novelty import nearest_cm
    from pipeline.train import export as ex

    monkeypatch.setenv("TWEEN_CACHE", str(tmp_path / "cache"))
    small = load_split("eval", limit=3)  # stands in for the train split (the same reading)
    monkeypatch.setattr(ex, "load_split", lambda split: small)
    plain = tmp_path / "plain"
    plain.mkdir()
    assert ex._pose_bank(plain, {"model": {"delta": False}}) == "pose_bank.npz"
    tuned = tmp_path / "tuned"
    tuned.mkdir()
    assert ex._pose_bank(tuned, {"model": {}, "data": str(takes), "data_include": None}) == "pose_bank.npz"
    a, b = posebank.load(plain / "pose_bank.npz"), posebank.load(tuned / "pose_bank.npz")
    studio = load_takes(takes)
    assert len(a) == min(posebank.POSES, len(small.rotations))
    assert len(b) == min(posebank.POSES // 2, len(small.rotations)) + min(
        posebank.POSES // 2, len(studio.rotations)
    )
    # The studio's poses are in the fine-tune's bank, and far from the Bandai-only one.
    feats = posebank.pose_features(
        studio.rotations[:: max(1, len(studio.rotations) // 50)],
        studio.roots[:: max(1, len(studio.rotations) // 50)],
    )
    assert np.median(nearest_cm(feats, b)) < 0.5 < np.median(nearest_cm(feats, a))
    assert ex._pose_bank(tmp_path, {"model": {"delta": True}}) is None
