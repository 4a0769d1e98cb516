"""Training and export never damage a model a studio has: bad input is refused before anything
is written, a finished model is replaced only with --force, and only once the new one is
complete (pipeline.staging)."""

from __future__ import annotations

import errno
import hashlib
import json
import shutil
from functools import partial
from pathlib import Path

import pytest

pytest.importorskip("torch")

from cli_contract import failed, refused, succeeded  # noqa: E402
from test_rig_fill import creature_shot  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
TINY = ["--steps", "4", "--path-steps", "0", "--batch", "2", "--lengths", "64", "--limit-clips", "1"]
NOT_HUMAN = """HIERARCHY
ROOT body
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT legA
  {
    OFFSET 10 -10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 -20 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.033333
0 30 0 0 0 0 0 0 0
0 30 1 0 0 0 5 0 0
"""


def _digest(folder: Path) -> dict:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}  # fmt: skip


@pytest.fixture
def model_folder(tmp_path) -> Path:
    """A copy of a finished generator model folder (its model.json and card)."""
    m = tmp_path / "studio_model"
    m.mkdir()
    for f in ("model.json", "MODEL_CARD.md"):
        shutil.copy(ROOT / "models" / "default" / f, m / f)
    return m


def test_train_refuses_bad_input_before_it_writes_anything(tmp_path, capsys, model_folder):
    out = tmp_path / "run"
    (tmp_path / "empty").mkdir()
    (tmp_path / "creature").mkdir()
    (tmp_path / "creature" / "q.bvh").write_text(NOT_HUMAN)
    (tmp_path / "junk.pt").write_bytes(b"\x80\x04 not a checkpoint")
    cases = {
        "no such folder of takes": ["--data", tmp_path / "missing"],
        "no BVH or USD takes": ["--data", tmp_path / "empty"],
        "q.bvh: joints do not map onto the model skeleton": ["--data", tmp_path / "creature"],
        "generator.onnx: --init: an ONNX export": ["--init", ROOT / "models/default/generator.onnx"],
        "junk.pt: --init: not a checkpoint that `tween train` wrote": ["--init", tmp_path / "junk.pt"],
        # Before the path predictor's minutes of training, not after them.
        "--device 'foo': must be cpu or cuda (cuda:N)": ["--device", "foo"],
        "--device cuda:99: torch sees ": ["--device", "cuda:99"],
        "--path-steps -1: must be from 0 to 1e+09": ["--path-steps", "-1"],
        "--data-include ' ,': names no file-name glob": [
            "--data",
            tmp_path / "creature",
            "--data-include",
            " ,",
        ],
        # A pack is read whole: --limit-clips (in TINY) would be ignored, not obeyed.
        "trains on every clip it holds; drop --limit-clips": ["--data-pack", tmp_path / "some.pack"],
    }
    for want, args in cases.items():
        line = refused(["train", "--out", out, *TINY, *args], capsys, tmp_path)
        assert want in line, line
    assert not out.exists()
    line = refused(["train", "--out", model_folder, *TINY], capsys, tmp_path)
    assert f"{model_folder}: --out (a run folder) holds a finished model (model.json)" in line


def test_train_refuses_an_empty_or_read_only_run_folder_before_it_writes(tmp_path, capsys, monkeypatch):
    """``--out ''`` trained into the working folder, and a run folder in a read-only one was
    written (root passes access checks): both are one line now, as for every other --out."""
    monkeypatch.chdir(tmp_path)
    ro = tmp_path / "published"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        for out, want in (("", "--out '': empty; give a path"), (" ", "--out ' ': empty"),
                          (ro / "run", f"--out is in {ro}, which is read-only")):  # fmt: skip
            assert want in refused(["train", "--out", out, *TINY], capsys, tmp_path)
            assert want in refused(
                ["train", "--out", out, "--recipe", "tween-bandai-delta-v3"], capsys, tmp_path
            )
        assert sorted(p.name for p in tmp_path.iterdir()) == ["published"] and not any(ro.iterdir())
    finally:
        ro.chmod(0o755)


def test_a_data_folder_without_the_capture_is_one_line_and_leaves_no_folders(tmp_path, capsys, monkeypatch):
    """TWEEN_DATA naming a folder without the Bandai capture was an internal error (exit 1,
    FileNotFoundError), and the run folder's parent it had made stayed."""
    monkeypatch.setenv("TWEEN_DATA", str(tmp_path / "nodata"))
    line = refused(["train", "--out", tmp_path / "runs" / "r1", *TINY], capsys, tmp_path)
    assert f"TWEEN_DATA {tmp_path / 'nodata'} is not the data folder" in line
    assert list(tmp_path.iterdir()) == []


def test_an_init_whose_weights_are_damaged_is_refused_before_the_run_folder_is_made(tmp_path, capsys):
    """Was an internal error with an empty run folder left (a state_dict mismatch, a negative
    width), or a run of NaN losses with exit 0 (NaN weights)."""
    import torch

    good = torch.load(ROOT / "models/default/torch/generator.pt", map_location="cpu", weights_only=False)
    model = good["config"]["model"]
    bad = {
        "holds values that are not finite (the run it comes from diverged)": {
            **good, "model": {k: v * float("nan") if v.is_floating_point() else v for k, v in good["model"].items()}
        },
        "size mismatch for inp.conv.weight": {**good, "model": {**good["model"], "inp.conv.weight": torch.zeros(3)}},
        "Trying to create tensor with negative dimension": {**good, "config": {**good["config"],
                                                                              "model": {**model, "width": -12}}},
        "its config is str, not a table": {**good, "config": "hello"},
    }  # fmt: skip
    out = tmp_path / "run"
    for i, (why, state) in enumerate(bad.items()):
        torch.save(state, tmp_path / f"init{i}.pt")
        line = refused(["train", "--out", out, *TINY, "--init", tmp_path / f"init{i}.pt"], capsys, tmp_path)
        assert line.startswith(f"tween: error: {tmp_path / f'init{i}.pt'}: --init: ") and why in line, line
        assert not out.exists()


def test_partial_keys_need_a_key_adapter_before_any_data_is_read(tmp_path, capsys):
    """--partial trains the key adapter: refused without --key-adapter unless the --init
    network has one, before the takes are looked at (--data names no folder here)."""
    import torch

    state = torch.load(ROOT / "models/default/torch/generator.pt", map_location="cpu", weights_only=False)
    assert state["config"]["model"]["key_adapter"]
    state["config"]["model"]["key_adapter"] = False
    torch.save(state, tmp_path / "no_adapter.pt")
    out, missing = tmp_path / "run", tmp_path / "missing"
    for init in ([], ["--init", tmp_path / "no_adapter.pt"]):
        line = refused(
            ["train", "--out", out, "--partial", "0.5", *init, "--data", missing, *TINY], capsys, tmp_path
        )
        assert "--partial 0.5: partial keys train the key adapter; give --key-adapter" in line, line
    for given in (["--key-adapter"], ["--init", ROOT / "models/default"]):  # the adapter given, or inherited
        line = refused(
            ["train", "--out", out, "--partial", "0.5", *given, "--data", missing, *TINY], capsys, tmp_path
        )
        assert "--partial" not in line and str(missing) in line, line
    assert not out.exists()
    # A recipe's stage goes straight to the training, which checks the same first.
    from pipeline.errors import TweenError
    from pipeline.train.generator_training import TrainConfig, train

    with pytest.raises(TweenError, match="--partial 0.5: partial keys train the key adapter"):
        train(TrainConfig(partial=0.5, data=str(missing)), out)
    assert not out.exists()


def test_export_replaces_a_model_only_with_force_and_only_when_complete(tmp_path, capsys, model_folder):
    run = tmp_path / "run"
    succeeded(["train", "--out", run, *TINY], capsys)
    before = _digest(model_folder)
    line = refused(["export", run, "--out", model_folder], capsys, tmp_path)
    assert "holds a finished model (model.json); give --force to replace it" in line
    line = refused(["export", tmp_path / "nowhere", "--out", tmp_path / "new"], capsys, tmp_path)
    assert "no generator.pt here" in line
    # A padding no fill could afford (10^8 frames asked 31 GiB of each), or below zero.
    for flag, value in (("--pad-tail", 100_000_000), ("--min-window", -1), ("--pad-tail", 1025)):
        line = refused(["export", run, "--out", model_folder, "--force", flag, value], capsys, tmp_path)
        assert (
            line == f"tween: error: {flag} {value}: must be 0 to 1024 frames (the fill's window grows by it)"
        )
    for bad in ("", " ", "a/b", ".."):  # model.json's name: what fills record, not a path
        line = refused(["export", run, "--out", model_folder, "--force", "--name", bad], capsys, tmp_path)
        assert line == f"tween: error: --name {bad!r}: a model name, not a path or nothing"
    assert _digest(model_folder) == before
    succeeded(["export", run, "--out", model_folder, "--force", "--name", "replaced"], capsys)
    assert '"name": "replaced"' in (model_folder / "model.json").read_text()
    assert (model_folder / "generator.onnx").is_file() and not (model_folder / "MODEL_CARD.md").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "studio_model"]  # no .partial, no .old


def test_export_refuses_a_checkpoint_whose_weights_are_damaged(tmp_path, capsys):
    import torch

    run = tmp_path / "run"
    succeeded(["train", "--out", run, *TINY], capsys)
    good = torch.load(run / "generator.pt", weights_only=False)
    bad = {
        # a run that diverged: its ONNX would agree with torch "within 0" (NaN drops out of max)
        "are not finite numbers (the run diverged)": {
            **good, "model": {k: v * float("nan") if v.is_floating_point() else v for k, v in good["model"].items()}
        },
        "size mismatch for inp.conv.weight": {**good, "model": {**good["model"], "inp.conv.weight": torch.zeros(3)}},
        "Missing key(s) in state_dict": {**good, "model": {}},
        "its config describes no network": {**good, "config": {"model": "abc"}},
    }  # fmt: skip
    for i, (why, state) in enumerate(bad.items()):
        damaged = tmp_path / f"damaged{i}"
        damaged.mkdir()
        torch.save(state, damaged / "generator.pt")
        line = refused(["export", damaged, "--out", tmp_path / "new"], capsys, tmp_path)
        assert (
            line.startswith(f"tween: error: {damaged / 'generator.pt'}: the run's checkpoint: ")
            and why in line
        )
        assert not (tmp_path / "new").exists() and not list(tmp_path.glob(".new*"))


def test_a_failed_export_leaves_the_model_as_it_was(tmp_path, capsys, model_folder, monkeypatch):
    import pipeline.train.export as export

    run = tmp_path / "run"
    succeeded(["train", "--out", run, *TINY], capsys)
    before = _digest(model_folder)

    def full_disk(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device", str(model_folder / "generator.onnx"))

    monkeypatch.setattr(export, "verify", full_disk)
    line = failed(["export", run, "--out", model_folder, "--force"], capsys)
    assert "No space left on device" in line
    assert _digest(model_folder) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "studio_model"]


def test_train_rig_never_trains_over_a_finished_model(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    clip = creature_shot(tmp_path / "clip.usda", T=61, keys_every=1)
    out = tmp_path / "models" / "creature"
    succeeded(["train-rig", clip, "--out", out, "--schedule", "tiny"], capsys)
    first = _digest(out)
    assert "rig.json" in first and not list(out.parent.glob(".*"))
    line = refused(["train-rig", clip, "--out", out, "--schedule", "tiny"], capsys, tmp_path)
    assert f"{out}: --out holds a finished model (rig.json); give --force" in line
    # The device rule `tween train` has (pipeline.rig.options.check_device): a CUDA index
    # this host lacks, not only "no CUDA at all".
    import torch

    n = torch.cuda.device_count() if torch.cuda.is_available() else 0
    line = refused(["train-rig", clip, "--out", out, "--force", "--schedule", "tiny", "--device", f"cuda:{n}"],
                   capsys, tmp_path)  # fmt: skip
    assert f"--device cuda:{n}: torch sees {n} CUDA device(s) on this host" in line
    assert _digest(out) == first
    # --force: a refusal (a clip too short) and a failure while exporting leave it as it was.
    short = creature_shot(tmp_path / "short.usda", T=13, keys_every=1)
    refused(["train-rig", short, "--out", out, "--force", "--schedule", "tiny"], capsys, tmp_path)
    import pipeline.rig.export as rig_export

    def full_disk(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device", str(out / "level_1.onnx"))

    with monkeypatch.context() as m:
        m.setattr(rig_export, "export", full_disk)
        line = failed(
            ["train-rig", clip, "--out", out, "--force", "--schedule", "tiny", "--seed", "3"], capsys
        )
        assert line.endswith("level_1.onnx: No space left on device")
    assert _digest(out) == first
    partial = out.parent / ".creature.partial"
    assert (partial / "checkpoints" / "state.pt").is_file()  # where the same command resumes
    # The same command again resumes there, exports, and swaps the new model in.
    succeeded(["train-rig", clip, "--out", out, "--force", "--schedule", "tiny", "--seed", "3"], capsys)
    assert _digest(out) != first and (out / "rig.json").is_file()
    assert sorted(p.name for p in out.parent.iterdir()) == ["creature"]


def test_a_run_folder_resumes_only_its_own_training(tmp_path, capsys, monkeypatch):
    """Resumed with other options, a run mixed two trainings under the new config (the
    export then named the wrong data); a longer --steps outran the learning-rate schedule and
    --init into a run of another shape failed in load_state_dict, both internal errors."""
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "run"
    succeeded(["train", "--out", "run", *TINY], capsys)  # a relative --out: the paths recorded absolute
    before = _digest(out)
    cases = {
        "steps: 4 there, 6 now": ["--steps", "6"],
        "init: None there, ": ["--init", ROOT / "models/default"],
        "lr: ": ["--lr", "0.01"],
    }
    for want, args in cases.items():
        line = refused(["train", "--out", out, *TINY, *args], capsys, tmp_path)
        assert "this run folder holds a training with other options" in line and want in line, line
    assert _digest(out) == before
    succeeded(["train", "--out", out, *TINY, "--threads", "1"], capsys)  # how it runs may change


class _Hours:
    """A clock each reading of which is an hour after the last: a checkpoint every step."""

    now = 0.0

    def time(self) -> float:
        self.now += 3600.0
        return self.now


@pytest.mark.parametrize("which", ["generator", "path"])
def test_a_resumed_run_logs_each_step_once(tmp_path, monkeypatch, which):
    """A run resumed from its last checkpoint logs again the steps it logged after it:
    train_log.jsonl (path_log.jsonl) held them twice. Here a line and a checkpoint every
    step, the run interrupted while it saved step 3's: it resumes from step 2's."""
    from pipeline.train import generator_training, path_training

    if which == "generator":
        module, log = generator_training, tmp_path / "train_log.jsonl"
        small = generator_training.GeneratorConfig(width=16, levels=(16, 16))
        cfg = generator_training.TrainConfig(steps=4, batch=2, lengths=(64,), limit_clips=1, model=small)
        run = partial(generator_training.train, cfg, tmp_path)
    else:
        module, log = path_training, tmp_path / "path_log.jsonl"
        run = partial(path_training.train_path, path_training.PathTrainConfig(steps=4, batch=2, threads=1, limit_clips=1), tmp_path)  # fmt: skip
    save = module.save_torch

    def interrupted_at_step_3(state, path):
        if state["step"] == 3:
            raise KeyboardInterrupt
        save(state, path)

    monkeypatch.setattr(module, "LOG_EVERY", 1)
    with monkeypatch.context() as m:
        m.setattr(module, "save_torch", interrupted_at_step_3)
        m.setattr(module, "time", _Hours())
        with pytest.raises(KeyboardInterrupt):
            run()
    assert [json.loads(line)["step"] for line in log.read_text().splitlines()] == [1, 2, 3]
    run()
    assert [json.loads(line)["step"] for line in log.read_text().splitlines()] == [1, 2, 3, 4]


def test_a_log_is_cut_back_whole_or_not_at_all(tmp_path, monkeypatch):
    """The lines after the checkpoint's step go, and a line a killed run left half-written;
    interrupted as it replaces the log, the log stays as it was, with no temporary beside it."""
    import os

    from pipeline.train.generator_training import resumed_log

    log = tmp_path / "train_log.jsonl"
    text = '{"step": 25}\n{"step": 50}\n{"step": 75}\n{"step": 10'
    log.write_text(text)

    def interrupted(src, dst):
        raise KeyboardInterrupt

    with monkeypatch.context() as m:
        m.setattr(os, "replace", interrupted)
        with pytest.raises(KeyboardInterrupt):
            resumed_log(log, 50)
    assert log.read_text() == text and os.listdir(tmp_path) == [log.name]
    with resumed_log(log, 50) as f:
        f.write('{"step": 75}\n')
    assert log.read_text() == '{"step": 25}\n{"step": 50}\n{"step": 75}\n'


def test_a_run_folder_another_training_holds_is_refused(tmp_path, capsys):
    """Two `tween train` into one --out wrote the same checkpoint's temporary name: one died
    with "generator.tmp -> generator.pt: No such file or directory" (exit 2, as bad input)."""
    from pipeline.atomic import holding

    out = tmp_path / "run"
    out.mkdir()
    with holding(out, busy=AssertionError):  # another training runs here
        line = refused(["train", "--out", out, *TINY], capsys, tmp_path)
    assert (
        line
        == f"tween: error: {out}: another `tween train` is writing this run folder; wait for it, or give another --out"
    )
    assert list(out.iterdir()) == []
    succeeded(["train", "--out", out, *TINY], capsys)  # and once it is done, the folder is free
    assert (out / "generator.pt").exists()


def test_takes_shorter_than_the_path_predictors_windows_are_refused(tmp_path, capsys, data_dir):
    """Takes of under 128 frames: numpy's "a cannot be empty" from the first path batch, an
    internal error (exit 1), and a run folder left with a log."""
    from pipeline.motion.bvh import read_bvh, write_bvh

    takes = tmp_path / "takes"
    takes.mkdir()
    clip = read_bvh(data_dir / "bandai_namco" / "dataset-2" / "dataset-2_walk_active_001.bvh.gz")
    write_bvh(clip.slice(0, 90), takes / "short.bvh")
    line = refused(["train", "--data", takes, "--out", tmp_path / "run", "--steps", "4", "--path-steps", "2",
                    "--lengths", "64", "--batch", "2"], capsys, tmp_path)  # fmt: skip
    assert (
        f"{takes}: no take of 128 frames (at 30 fps) for the path predictor's windows; the longest is" in line
    )
    assert "--path-steps 0" in line and not (tmp_path / "run").exists()


def test_a_path_checkpoint_is_written_whole_and_a_damaged_one_named(tmp_path, capsys, monkeypatch):
    """torch.save wrote path.pt in place: a run killed while it saved left a truncated file,
    and every resume failed with an internal error (EOFError), exit 1."""
    import torch

    out = tmp_path / "run"
    args = ["train", "--out", out, *TINY[:2], "--path-steps", "2", *TINY[4:]]
    real = torch.save

    def killed(obj, f, *a, **k):  # half the file, then the kill
        real(obj, f, *a, **k)
        Path(f).write_bytes(Path(f).read_bytes()[:600])
        raise KeyboardInterrupt

    monkeypatch.setattr(torch, "save", killed)
    with pytest.raises((KeyboardInterrupt, SystemExit)):
        from pipeline.cli import main

        main([str(a) for a in args])
    monkeypatch.setattr(torch, "save", real)
    assert not (out / "path.pt").exists() and not [p for p in out.iterdir() if p.suffix == ".tmp"]
    succeeded(args, capsys)  # resumes: nothing half-written is read
    (out / "path.pt").write_bytes((out / "path.pt").read_bytes()[:600])
    line = refused(args, capsys)
    assert line.startswith(f"tween: error: {out / 'path.pt'}: the run's path checkpoint: not a checkpoint")


def test_an_interrupt_just_after_the_run_folder_is_made_leaves_none(tmp_path, monkeypatch):
    """Ctrl-C while torch imported is sent again until it lands outside the import
    (pipeline.command); one landed just after train_run made the run folder, before its
    cleanup began, and left ``--out`` empty (1 in 20 Ctrl-Cs 0.5-0.9 s into `tween train`)."""
    from interrupt_fixtures import interrupt_after_mkdir

    from pipeline.train.recipe import train_run

    interrupt_after_mkdir(monkeypatch)
    with pytest.raises(KeyboardInterrupt):
        train_run(tmp_path / "runs" / "r1", None, None)
    assert list(tmp_path.iterdir()) == []


def test_an_out_inside_a_file_is_named_as_the_user_gave_it(tmp_path, capsys, bandai_clip):
    """Making the model beside --out said "…/afile/.model.partial: Not a directory"."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "generator.pt").write_bytes(b"")  # refused before it is read
    afile = tmp_path / "afile"
    afile.write_text("a file")
    for cmd in (["export", run], ["train-rig", bandai_clip, "--schedule", "tiny"]):
        line = refused([*cmd, "--out", afile / "model"], capsys, tmp_path)
        assert (
            line == f"tween: error: {afile / 'model'}: --out is inside {afile}, which is a file, not a folder"
        )


class _Trained(Exception):
    """Raised where a stage would have begun training (train_run, or the path predictor)."""


def test_a_damaged_pack_is_refused_before_the_path_predictor_trains(tmp_path, capsys, monkeypatch):
    """`tween train --data-pack` read the pack only when the generator's training began: after
    the path predictor's 2000 default steps (minutes on the train split), a pack cut short or
    no pack at all was an internal error (MemoryError, JSONDecodeError, LZMAError), exit 1."""
    import time

    from test_pack_damaged import tiny_clips

    import pipeline.train.path_training as path_training
    from pipeline.data.pack import pack

    def trained(*a, **k):
        raise _Trained("the path predictor trained before the pack was checked")

    monkeypatch.setattr(path_training, "train_path", trained)
    good = pack(tiny_clips(), tmp_path / "good.pack").read_bytes()
    pack(tiny_clips(joints=5), tmp_path / "five.pack")
    cases = {
        "huge.pack": (b'{"rot_bytes": 99999999999, "root_bytes": 1}\nxx', "its header has no names"),
        "garbage.pack": (b"garbage\n", "its first line is no JSON header"),
        "cut.pack": (good[:-100], "bytes of data after it, the file holds"),
        "empty.pack": (b"", "cut short in its header"),
        "missing.pack": (None, "cannot read it: No such file or directory"),
        "five.pack": (None, "its clips have 5 joints, the model skeleton 21"),  # (packed above)
    }
    out = tmp_path / "run"
    for name, (data, why) in cases.items():
        if isinstance(data, bytes):
            (tmp_path / name).write_bytes(data)
        t0 = time.monotonic()
        line = refused(["train", "--out", out, "--data-pack", tmp_path / name], capsys, tmp_path)
        assert line.startswith(f"tween: error: {tmp_path / name}: --data-pack: ") and why in line, line
        assert time.monotonic() - t0 < 20
    assert not out.exists()


PACKED_RECIPE = """name = "packed"
[[stage]]
name = "s1"
args = "--path-steps 0 --steps 4 --batch 2 --lengths 64"
[[stage]]
name = "s2"
init = "s1"
packed = true
args = "--path-steps 0 --steps 4 --batch 2 --lengths 64"
"""


def test_a_recipe_refuses_its_damaged_pack_before_its_first_stage_trains(tmp_path, capsys, monkeypatch):
    """A packed stage's OUT/train.pack, cut short, was read when that stage began: after the
    stages before it had trained. One the runner has yet to make is no refusal."""
    import pipeline.train.recipe as recipe

    def train_run(run, cfg, path_cfg):
        raise _Trained(run.name)

    monkeypatch.setattr(recipe, "train_run", train_run)
    (tmp_path / "packed.toml").write_text(PACKED_RECIPE)
    out = tmp_path / "runs"
    out.mkdir()
    (out / "train.pack").write_bytes(b'{"names": ["a"], "lengths": [2]')
    line = refused(["train", "--recipe", tmp_path / "packed.toml", "--out", out], capsys, tmp_path)
    assert line == (
        f"tween: error: {tmp_path / 'packed.toml'}: stage 's2': {out / 'train.pack'}: --data-pack: not a "
        "training pack written by python -m pipeline.data.pack (cut short in its header); pack the split again"
    )
    (out / "train.pack").unlink()  # made by the runner before s2 trains
    with pytest.raises(_Trained, match="s1"):
        recipe.run_recipe(recipe.load_recipe(tmp_path / "packed.toml"), out)
