"""The per-rig GANimator core: topology, pyramid, training, export, filling (issue 7)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import TweenError
from pipeline.motion.clip import Motion
from pipeline.motion.rotations import euler_to_quat
from pipeline.motion.skeleton import Skeleton
from pipeline.rig.topology import neighbourhoods

REPO = Path(__file__).resolve().parents[2]
# hips, spine, head, left hip/knee/ankle, right hip/knee/ankle (cm, Y-up)
PARENTS = [-1, 0, 1, 0, 3, 4, 0, 6, 7]
NAMES = ["hips", "spine", "head", "l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle"]
OFFSETS = [
    [0, 80, 0],
    [0, 20, 0],
    [0, 20, 0],
    [10, 0, 0],
    [0, -40, 0],
    [0, -40, 0],
    [-10, 0, 0],
    [0, -40, 0],
    [0, -40, 0],
]


def walk(n: int = 96, fps: float = 30.0, up: str = "Y") -> Motion:
    """Marching in place on a 9-joint biped: each leg lifts for half a cycle (hip and knee
    bend) and stands straight, planted, for the other half; the body turns and sways."""
    t = np.arange(n) / fps
    w = 2 * np.pi * 1.2 * t
    eul = np.zeros((n, 9, 3))
    eul[:, 0, 1] = 15 * np.sin(0.5 * w)
    eul[:, 1, 0] = 5 * np.sin(w)
    eul[:, 2, 2] = 10 * np.sin(0.7 * w)
    for hip, knee, ph in ((3, 4, 0.0), (6, 7, np.pi)):
        lift = np.clip(np.sin(w + ph), 0, None)
        eul[:, hip, 0] = -35 * lift
        eul[:, knee, 0] = 60 * lift
    rot = euler_to_quat(eul, "XYZ")
    root = np.stack([2 * np.sin(w), np.full(n, 80.0), np.zeros(n)], -1)
    offsets = np.array(OFFSETS, np.float32)
    if up == "Z":  # the same motion authored Z-up: turn the root by +90° about X
        from pipeline.motion.rotations import quat_apply, quat_mul

        fix = np.array([np.sqrt(0.5), 0, 0, np.sqrt(0.5)])
        rot[:, 0] = quat_mul(np.broadcast_to(fix, rot[:, 0].shape), rot[:, 0])
        root = quat_apply(fix, root)
        offsets[0] = quat_apply(fix, offsets[0])
    sk = Skeleton(tuple(NAMES), np.array(PARENTS), offsets, up, 0.01)
    return Motion(sk, rot.astype(np.float32), root.astype(np.float32), fps, "walk")


@pytest.fixture(scope="session")
def tiny_model(tmp_path_factory):
    """A tiny model trained once per session, exported to ONNX."""
    pytest.importorskip("torch")
    from pipeline.rig.export import export
    from pipeline.rig.train import TrainConfig, train

    out = tmp_path_factory.mktemp("rig")
    cfg = TrainConfig(
        source="walk", out=str(out), schedule="tiny", iters=25, seed=0, licence="test", name="walk"
    )
    tr = train(cfg, walk(), quiet=True)
    meta = export(tr, out)
    return tr, meta, out


def test_neighbourhoods_exact_on_a_hand_made_rig():
    # root 0; chain 0-1-2-3 (foot 3) and 0-4-5-6 (foot 6); contacts on 3 and 6
    nb = neighbourhoods([-1, 0, 1, 2, 0, 4, 5], [3, 6])
    assert nb == [
        [0, 1, 2, 4, 5, 9],
        [0, 1, 2, 3, 4, 9],
        [0, 1, 2, 3, 9],
        [1, 2, 3, 7, 9],  # foot: its chain, its contact vertex, the root vertex (via the contact)
        [0, 1, 4, 5, 6, 9],
        [0, 4, 5, 6, 9],
        [4, 5, 6, 8, 9],
        [1, 2, 3, 7, 9],  # contact vertex: its foot's neighbourhood
        [4, 5, 6, 8, 9],
        [0, 1, 2, 4, 5, 7, 8, 9],  # root displacement: the root's joints, every contact, itself
    ]


def test_skeleton_conv_reads_only_neighbours():
    torch = pytest.importorskip("torch")
    from pipeline.rig.networks import SkeletonConv

    nb = neighbourhoods([-1, 0, 1, 2, 0, 4, 5], [3, 6])
    conv = SkeletonConv(nb, 60, 30)
    x = torch.zeros(1, 60, 9)
    x[0, 6 * 6 : 6 * 7] = 1.0  # only joint 6 is non-zero
    with torch.no_grad():
        y = conv(x) - conv(torch.zeros_like(x))
    moved = {v for v in range(10) if y[0, 3 * v : 3 * v + 3].abs().max() > 0}
    assert moved == {4, 5, 6, 8}  # the vertices whose neighbourhood holds joint 6


def test_representation_round_trip_and_z_up():
    from pipeline.rig.represent import decode, encode, make_spec

    for up in ("Y", "Z"):
        m = walk(up=up)
        spec = make_spec(m)
        assert [m.skeleton.names[j] for j in spec.contacts] == ["l_ankle", "r_ankle"]
        assert spec.channels == 6 * (9 + 2 + 1)
        feat, begin = encode(m, spec)
        back, contacts = decode(feat, spec, begin)
        assert np.abs(back.positions() - m.positions()).max() < 1e-3
        assert 0.2 < contacts.mean() < 0.9  # planted part of the time, not always
    # Z-up and Y-up versions of one walk give the same features (the frame is Y-up inside).
    fy, _ = encode(walk(), make_spec(walk()))
    fz, _ = encode(walk(up="Z"), make_spec(walk(up="Z")))
    assert np.abs(fy - fz).max() < 1e-4


def test_pyramid_lengths_follow_the_official_rule():
    from pipeline.rig.represent import pyramid_lengths

    assert pyramid_lengths(600, 1 / 5) == [120, 160, 213, 284, 378, 504, 600]
    assert pyramid_lengths(371, 1 / 5) == [74, 98, 130, 173, 230, 306, 371]
    assert pyramid_lengths(140, 1 / 5) == [28, 37, 49, 65, 86, 114, 140]
    assert pyramid_lengths(632, 1 / 30)[:3] == [21, 28, 37] and len(pyramid_lengths(632, 1 / 30)) == 13


def test_up_axis_seen_from_skeleton_space():
    from pipeline.rig.source import _up_in_skeleton

    rx90 = np.eye(4)
    rx90[1:3, 1:3] = [[0, -1], [1, 0]]  # skeleton Y → world Z
    ry180 = np.diag([-1.0, 1, -1, 1])  # the elephant's root prim: a turn about Y
    assert _up_in_skeleton("Y", np.eye(4)) == "Y" and _up_in_skeleton("Z", np.eye(4)) == "Z"
    assert _up_in_skeleton("Z", rx90) == "Y" and _up_in_skeleton("Y", ry180) == "Y"
    assert _up_in_skeleton("Y", np.diag([1.0, -1, -1, 1])) == ""  # upside down: refused


def test_shapes_through_the_pyramid(tiny_model):
    torch = pytest.importorskip("torch")
    tr, meta, _ = tiny_model
    assert tr.lengths == [19, 25, 33, 44, 58, 77, 96]
    with torch.no_grad():
        outs = tr.chain(len(tr.lengths) - 1, len(tr.lengths))
        recs = tr.reconstruction(len(tr.lengths) - 1)
    assert [tuple(o.shape) for o in outs] == [(1, tr.F, n) for n in tr.lengths]
    assert [tuple(o.shape) for o in recs] == [(1, tr.F, n) for n in tr.lengths]
    with torch.no_grad():
        assert tuple(tr.D[3](outs[3]).shape) == (1, 1, tr.lengths[3])


def test_tiny_model_loss_falls(tiny_model):
    tr, _, _ = tiny_model
    first = [e for e in tr.log if e["group"] == 0]
    assert first[-1]["rec"] < 0.7 * first[0]["rec"]
    assert all(np.isfinite(e["d"]) and np.isfinite(e["adv"]) for e in tr.log)


def test_onnx_matches_torch(tiny_model):
    import onnxruntime as ort
    import torch

    tr, meta, out = tiny_model
    assert meta["onnx_max_abs_diff"] < 1e-4
    rng = np.random.default_rng(3)
    up = rng.standard_normal((1, tr.F, 41)).astype(np.float32)
    z = rng.standard_normal((1, 1, 41)).astype(np.float32)
    sess = ort.InferenceSession(str(out / meta["files"]["levels"][4]), providers=["CPUExecutionProvider"])
    with torch.no_grad():
        ref = tr.G[4](torch.from_numpy(up), torch.from_numpy(z)).numpy()
    assert np.abs(sess.run(["out"], {"up": up, "z": z})[0] - ref).max() < 1e-4


def test_rig_json_contract(tiny_model):
    _, meta, out = tiny_model
    for k in ("kind", "name", "hash", "fps", "skeleton", "contact_joints", "source", "licence", "files"):
        assert k in meta
    assert meta["kind"] == "rig"
    assert meta["skeleton"]["names"] == NAMES and meta["skeleton"]["parents"] == PARENTS
    assert np.allclose(meta["skeleton"]["offsets"], OFFSETS)
    assert meta["contact_joints"] == ["l_ankle", "r_ankle"] and meta["ik_joints"] == ["l_ankle", "r_ankle"]
    assert (out / "MODEL_CARD.md").read_text().count("walk") >= 1
    # Every model folder states its terms (models/README.md): the clip's licence as --licence
    # stated it ("test" rules nothing out; the guess "unknown (set --licence)" would).
    assert meta["sources"] == [
        {"name": meta["sources"][0]["name"], "licence": "test", "frames": meta["source"]["train_frames"],
         "fps": meta["fps"], "use": "trained"}
    ]  # fmt: skip
    assert meta["commercial"] is True and "walk" in meta["sources"][0]["name"]


def test_fill_keys_exact_and_seeds(tiny_model):
    from pipeline.rig.infer import RigInbetweener

    _, _, out = tiny_model
    inb = RigInbetweener(out)
    m = walk(130)  # longer than the training clip: fully convolutional
    keys = np.array([5, 35, 65, 95, 125])
    a = inb.fill(m, keys, seed=1)
    assert len(a) == len(m)
    assert np.array_equal(a.rotations[keys], m.rotations[keys])
    assert np.array_equal(a.root_positions[keys], m.root_positions[keys])
    assert np.array_equal(a.rotations[:5], np.repeat(m.rotations[5:6], 5, 0))  # held before the first key
    assert np.array_equal(a.root_positions[126:], np.repeat(m.root_positions[125:126], 4, 0))
    b = inb.fill(m, keys, seed=1)
    c = inb.fill(m, keys, seed=2)
    assert np.array_equal(a.rotations, b.rotations) and np.array_equal(a.root_positions, b.root_positions)
    assert np.abs(a.rotations - c.rotations).max() > 1e-4
    # Only the key frames are read: garbage elsewhere changes nothing.
    junk = Motion(m.skeleton, m.rotations.copy(), m.root_positions.copy(), m.fps)
    off = np.setdiff1d(np.arange(len(m)), keys)
    junk.rotations[off] = np.nan
    junk.root_positions[off] = 1e6
    d = inb.fill(junk, keys, seed=1)
    assert np.array_equal(a.rotations, d.rotations) and np.array_equal(a.root_positions, d.root_positions)
    for short in ([0, 1, 2, 5, 12], [3, 7]):  # adjacent keys, tiny gaps, a span below MIN_FRAMES
        e = inb.fill(m, np.array(short), seed=0)
        assert np.array_equal(e.rotations[short], m.rotations[short]) and np.isfinite(e.rotations).all()
    assert np.isfinite(a.rotations).all() and np.allclose(np.linalg.norm(a.rotations, axis=-1), 1, atol=1e-4)


def test_synthesize_seeds_and_length(tiny_model):
    from pipeline.rig.infer import RigInbetweener

    inb = RigInbetweener(tiny_model[2])
    a, b, c = inb.synthesize(150, seed=4), inb.synthesize(150, seed=4), inb.synthesize(150, seed=5)
    assert len(a) == 150 and a.skeleton.names == tuple(NAMES)
    assert np.array_equal(a.rotations, b.rotations)
    assert np.abs(a.rotations - c.rotations).max() > 1e-4


def test_fill_never_imports_torch(tiny_model):
    code = (
        "import sys, numpy as np\n"
        "sys.path.insert(0, 'tests/rig')\n"
        "from test_rig_core import walk\n"
        "from pipeline.rig.infer import RigInbetweener\n"
        f"inb = RigInbetweener({str(tiny_model[2])!r})\n"
        "inb.fill(walk(), np.array([0, 30, 60, 95]))\n"
        "assert 'torch' not in sys.modules, 'torch imported'\n"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]


def test_resume_gives_the_same_weights(tmp_path):
    torch = pytest.importorskip("torch")
    from pipeline.rig.train import TrainConfig, Trainer, train

    def cfg(out):
        return TrainConfig(source="walk", out=str(out), schedule="tiny", iters=4, seed=7, ckpt_every=2)

    whole = train(cfg(tmp_path / "a"), walk(), quiet=True)
    calls = {"n": 0}
    step = Trainer.step

    def dying(self, *a):
        calls["n"] += 1
        if calls["n"] == 8:  # iteration 4 of the second group, after its checkpoint at iteration 2
            raise KeyboardInterrupt
        return step(self, *a)

    Trainer.step = dying
    try:
        with pytest.raises(KeyboardInterrupt):
            train(cfg(tmp_path / "b"), walk(), quiet=True)
    finally:
        Trainer.step = step
    resumed = train(cfg(tmp_path / "b"), walk(), quiet=True)
    for g1, g2 in zip(whole.G, resumed.G, strict=True):
        for p1, p2 in zip(g1.parameters(), g2.parameters(), strict=True):
            assert torch.equal(p1, p2)


def test_bad_inputs_one_line_naming_the_file(tmp_path):
    from pipeline.rig.source import load_rig_source

    with pytest.raises(TweenError, match=r"nope\.usda: file not found"):
        load_rig_source(tmp_path / "nope.usda")
    with pytest.raises(
        TweenError, match=r"sh010_walk\.usda: skeleton '/No/Such' is not an animated skeleton"
    ):
        load_rig_source(REPO / "examples/sh010_walk.usda", skeleton="/No/Such")
    bad = tmp_path / "clip.bvh"
    bad.write_text("HIERARCHY\nROOT a\n{\n")
    with pytest.raises(TweenError, match=r"clip\.bvh"):
        load_rig_source(bad)
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "pipeline.cli",
            "train-rig",
            str(tmp_path / "gone.bvh"),
            "--out",
            str(tmp_path / "m"),
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [f"tween: error: {tmp_path / 'gone.bvh'}: file not found"]
    assert not (tmp_path / "m").exists()


def _damaged_npz(tmp_path, name, **change) -> Path:
    from pipeline.rig.source import save_npz

    path = tmp_path / f"{name}.npz"
    save_npz(walk(), path)
    z = dict(np.load(path))
    z.update(change)
    np.savez(path, **z)
    return path


def test_a_damaged_clip_npz_is_one_line_naming_it(tmp_path):
    """Before: a truncated .npz was BadZipFile (exit 1); NaN offsets or a rate of 0 trained
    and exported a rig.json full of NaN."""
    from pipeline.rig.source import load_rig_source, save_npz

    good = tmp_path / "good.npz"
    save_npz(walk(), good)
    cut = tmp_path / "cut.npz"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    offsets = np.asarray(walk().skeleton.offsets).copy()
    offsets[1, 0] = np.nan
    cases = {
        cut: "not a clip .npz written by `tween rig-extract`",
        _damaged_npz(tmp_path, "nan", offsets=offsets): "its offsets hold NaN or infinite values",
        _damaged_npz(tmp_path, "still", fps=np.array(0.0)): "frame rate 0.0: not a positive number",
        _damaged_npz(tmp_path, "inf", root_positions=np.full((96, 3), np.inf)): "root positions hold NaN",
        _damaged_npz(
            tmp_path, "short", parents=np.array([-1])
        ): "names, parents and offsets differ in length",
    }
    rot = walk().rotations.copy()
    rot[5, 2] = 0
    nan = walk().rotations.copy()
    nan[0, 0, 0] = np.nan
    # Before: all-zero quaternions, 0 joints or a joint name twice were accepted, then crashed
    # ("Found zero norm quaternions", IndexError) or trained a rig.json no fill could match.
    cases |= {
        _damaged_npz(tmp_path, "zero", rotations=rot): (
            "rotations: joint 'head' at frame 5 is not a rotation (quaternion (0, 0, 0, 0) has length 0)"
        ),
        _damaged_npz(tmp_path, "nanq", rotations=nan): "its rotations hold NaN",
        _damaged_npz(
            tmp_path,
            "nojoints",
            names=np.array([], str),
            parents=np.zeros(0, int),
            offsets=np.zeros((0, 3)),
            rotations=np.zeros((96, 0, 4)),
        ): "names: the skeleton has no joints",
        _damaged_npz(
            tmp_path, "twice", names=np.array(NAMES[:8] + ["hips"])
        ): "joint name 'hips' is given twice",
    }
    for path, says in cases.items():
        with pytest.raises(TweenError) as e:
            load_rig_source(path)
        assert str(e.value).startswith(f"{path}: ") and says in str(e.value), str(e.value)
    assert len(load_rig_source(good)) == 96
    long = walk().rotations.copy()  # a key of another length is a rotation (the USD reader's rule)
    long[7, 1] *= 2
    assert len(load_rig_source(_damaged_npz(tmp_path, "long", rotations=long))) == 96


def test_rig_json_names_a_shared_clip_relative_to_the_shared_folder(data_dir, tmp_path):
    from pipeline.rig.source import portable_path, stored_path

    clip = data_dir / "usd_assets" / "RiggedSimple"
    first = sorted(p for p in clip.rglob("*") if p.is_file())[0]
    stored = portable_path(first)
    assert stored.startswith("shared:") and "/work" not in stored and str(data_dir) not in stored
    assert stored_path(stored).resolve() == first.resolve()
    other = tmp_path / "walk.bvh"
    assert portable_path(other) == str(other) and stored_path(str(other)) == other
    # The shipped creature model's clip resolves in any checkout with the shared data beside it.
    import json
    from pathlib import Path

    meta = json.loads((Path(__file__).resolve().parents[2] / "models/elephant/rig.json").read_text())
    assert stored_path(meta["source"]["path"]).is_file()


def test_rig_extract_writes_only_the_npz_it_names_and_replaces_only_with_force(tmp_path, capsys):
    """Before: an existing OUT was replaced without a word, and an OUT without .npz (or a
    folder) was reported as written while numpy wrote OUT.npz beside it."""
    from cli_contract import refused

    from pipeline.cli import main
    from pipeline.rig.source import load_rig_source

    shot = REPO / "examples" / "sh010_walk.usda"
    out = tmp_path / "clip.npz"
    out.write_bytes(b"the user's own file")
    (tmp_path / "folder.npz").mkdir()
    cases = {
        (out,): f"{out}: exists; give --force to replace it",
        (tmp_path / "clip",): f"{tmp_path / 'clip'}: OUT must name an .npz file",
        (tmp_path / "folder.npz",): f"{tmp_path / 'folder.npz'}: is a folder",
        (tmp_path / "no" / "c.npz",): f"{tmp_path / 'no'}: no such folder for OUT",
    }
    for (target,), says in cases.items():
        line = refused(["rig-extract", shot, target], capsys, tmp_path)
        assert line.startswith(f"tween: error: {says}"), line
    line = refused(["rig-extract", shot, tmp_path / "s.npz", "--skeleton", " "], capsys, tmp_path)
    assert line.startswith("tween: error: --skeleton ' ': empty"), line  # was read as not given
    assert out.read_bytes() == b"the user's own file"
    with pytest.raises(SystemExit) as e:
        main(["rig-extract", str(shot), str(out), "--force"])
    assert e.value.code == 0
    assert len(load_rig_source(out)) == len(load_rig_source(shot))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.npz", "folder.npz"]  # no temporary left
    umask = os.umask(0)
    os.umask(umask)
    assert out.stat().st_mode & 0o777 == 0o666 & ~umask  # as a file the user writes, not private
