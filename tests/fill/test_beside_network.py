"""The network the default ships beside its own (models/default/delta, the delta model):
probed after the library on keys unlike the network's training data, decided on only where
its probes beat the spline by its floor and the network by the margin; refused bad
``"beside"`` entries; its licence in the fill."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from usd_fixtures import ANIM, BANDAI_CLIP, cmu_shot

from pipeline.fill.api import fill_shot
from pipeline.fill.options import FillOptions
from pipeline.infer.api import load_inbetweener
from pipeline.infer.folder import ModelFolderError, models_root
from pipeline.infer.spline import SplineInbetweener
from pipeline.infer.trust import TrustedInbetweener, choice_rule, pick, trusted_fill_windows
from pipeline.library.infer import LibraryInbetweener
from pipeline.motion.augment import posture_offsets
from pipeline.motion.clip import Motion
from pipeline.usd.take import model_take

DELTA = "tween-bandai-delta-v3"


def test_the_default_ships_the_delta_network_inside_its_folder():
    net = load_inbetweener("default")
    assert net.beside_folders == (net.folder / "delta",)
    # One network in two places: the copy a fill probes is the delta model's, byte for byte.
    inside, alone = net.beside_folders[0], models_root() / "delta"
    assert (inside / "generator.onnx").read_bytes() == (alone / "generator.onnx").read_bytes()
    assert json.loads((inside / "model.json").read_text()) == json.loads((alone / "model.json").read_text())


def test_choice_rule_takes_each_candidates_margin():
    net = load_inbetweener("default")
    lib = LibraryInbetweener(str(net.library_folder))
    delta = load_inbetweener(str(net.beside_folders[0]))
    # Margins: what a later candidate must beat each by (the network's, the library's, the
    # delta network's); the floor: what each alternative must beat the spline by.
    assert choice_rule(net, (lib, delta)) == ([0.25, 0.25, 0.25], 0.0)
    # A studio library as the primary keeps nothing of its own: no floor, its own margin.
    assert choice_rule(lib, (net,)) == ([0.25, 0.25], None)


def test_pick_in_order_with_a_margin_per_candidate():
    floors, margins = 0.0, [0.25, 0.25, 0.25]
    # The delta network must beat the library as well as the network by their margins: the
    # probes' holes, twice the shot's gaps, undersell a library against a network.
    assert pick([-0.32, 0.11, 0.12], margins, floors) == 1
    assert pick([-0.15, 0.0, 0.14], margins, floors) == 0  # beats the network, not the library
    assert pick([-0.58, 0.04, 0.78], margins, floors) == 2
    assert pick([None, None, 0.2], margins, floors) == 2 and pick([None, 0.0, 0.2], margins, floors) == 0
    # The floor: an alternative under it is passed over (its margin still counts for later ones).
    assert pick([-1.0, -0.01, 0.3], margins, 0.0) == 2 and pick([-1.0, 0.0, 0.3], margins, 0.5) == 0
    # One number is the primary's margin, as before: the alternatives then by their scores.
    assert pick([-1.0, 0.04, 0.3], 0.25, 0.0) == 2 and pick([0.2, 0.04, 0.3], 0.25, 0.0) == 0


def test_a_walk_on_another_posture_is_the_delta_networks():
    """The training studio's walk with 30 degree posture offsets on every joint (a rig set up
    otherwise), keyed every 10 frames: the network fails on it, the delta network does not, and
    the probes see it; the batched windows choose as the fill does. (Keyed every 30 the probes'
    60-frame holes find the delta network worse than the spline on this walk: the network keeps
    it and its trusted fill leans on the spline.)"""
    every = 10
    net = load_inbetweener("default")
    lib = LibraryInbetweener(str(net.library_folder))
    delta = load_inbetweener(str(net.beside_folders[0]))
    spline = SplineInbetweener(net.skeleton)
    walk = model_take(BANDAI_CLIP, 30.0)
    T = 91
    rots = posture_offsets(walk.rotations[None, :T], np.random.default_rng(0), 30.0, 1.0).astype(np.float32)
    roots = walk.root_positions[None, :T].astype(np.float32)
    keys = np.r_[np.arange(0, T - 1, every), T - 1]
    f = trusted_fill_windows(net, spline, rots, roots, keys, alternatives=(lib, delta))
    one = TrustedInbetweener(net, spline, alternatives=(lib, delta))
    got = one.fill(Motion(net.skeleton, rots[0], roots[0], 30.0), keys)
    d = one.last_decision
    assert d.source == DELTA and f.decisions[0].source == DELTA and list(f.chosen) == [2]
    scores = {c["name"]: c["score"] for c in d.candidates}
    assert scores[DELTA] > max(0.1, scores["tween-bandai-v5.3"] + 0.25)
    np.testing.assert_allclose(f.decided[1][0], got.root_positions, atol=1e-4)
    # What it fills is nearer the truth than the spline between the keys.
    free = np.setdiff1d(np.arange(T), keys)
    truth = Motion(net.skeleton, rots[0], roots[0], 30.0).positions()[free]
    spl = spline.fill(Motion(net.skeleton, rots[0], roots[0], 30.0), keys).positions()[free]
    assert (
        np.linalg.norm(got.positions()[free] - truth, axis=-1).mean()
        < np.linalg.norm(spl - truth, axis=-1).mean()
    )


def test_an_unfamiliar_shot_probes_it_and_names_its_licence(tmp_path, capsys):
    shot = cmu_shot(tmp_path / "cc.usda", frames=121, keys_every=12)
    res = fill_shot(str(shot), FillOptions(model="default", out_dir=str(tmp_path / "out")))
    said = f"human model tween-bandai-v5.3, with library:cmu-subjects-1-3 and {DELTA} probed beside it"
    assert said in capsys.readouterr().err
    assert DELTA in {c["name"] for c in res["trust"][ANIM]["candidates"]}
    assert res["licence"][DELTA].startswith("CC BY-NC 4.0") and "CMU Graphics Lab" in res["licence"][DELTA]
    # --trust model is the network alone: nothing is probed beside it.
    alone = fill_shot(str(shot), FillOptions(model="default", trust="model", out_dir=str(tmp_path / "net")))
    assert DELTA not in alone["licence"]


@pytest.mark.parametrize(
    "beside, why",
    [
        (["/abs/delta"], "must list folders inside the model folder"),
        (["../delta"], "must list folders inside the model folder"),
        ([7], "must list folders inside the model folder"),
        (["nothing"], "names 'nothing', which holds no model.json"),
    ],
)
def test_a_bad_beside_entry_is_one_line_naming_model_json(tmp_path, beside, why):
    folder = tmp_path / "m"
    shutil.copytree(
        models_root() / "default", folder, ignore=shutil.ignore_patterns("torch", "bench", "*.md")
    )
    meta = json.loads((folder / "model.json").read_text())
    (folder / "model.json").write_text(json.dumps(meta | {"beside": beside}))
    with pytest.raises(ModelFolderError, match=why) as e:
        load_inbetweener(str(folder))
    assert str(folder / "model.json") in str(e.value) and "\n" not in str(e.value)
