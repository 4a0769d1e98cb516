"""The library the default model ships beside its network (models/default/library, CMU
subjects 1-3): probed on the shot's own keys beside the network, the better deciding, and
recorded like a studio's library; the benches' batched windows choose as the fill does."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from pxr import Usd
from usd_fixtures import ANIM, BANDAI_CLIP, CMU_CLIP, FILLED, bandai_shot, cmu_shot

from pipeline.fill.api import fill_shot
from pipeline.fill.options import FillOptions
from pipeline.infer.api import load_inbetweener
from pipeline.infer.spline import SplineInbetweener
from pipeline.infer.trust import TrustedInbetweener, pick, trusted_fill_windows
from pipeline.library.infer import LibraryInbetweener
from pipeline.motion.clip import Motion
from pipeline.usd.take import model_take
from usd_schemas import tokens

LIB = "library:cmu-subjects-1-3"


def test_the_default_ships_a_library_it_probes_beside_the_network():
    net = load_inbetweener("default")
    assert net.library_folder is not None and (net.library_folder / "library.json").is_file()
    manifest = json.loads((net.library_folder / "library.json").read_text())
    # Only trainable, commercially usable takes of subjects the benches do not hold out, and no
    # machine's paths.
    assert {t["name"][:3] for t in manifest["takes"]} == {"001", "002", "003"}
    assert all(
        not t["file"].startswith("/") and t["file"].startswith("cmu_iclone/") for t in manifest["takes"]
    )
    assert manifest["licence"].startswith("CMU Graphics Lab")


def test_a_take_of_the_library_is_filled_from_it_and_recorded(tmp_path):
    # A CMU subject 1 take: the library holds it, so its probes beat the network's.
    shot = cmu_shot(tmp_path / "cc.usda", frames=121, keys_every=12)
    res = fill_shot(str(shot), FillOptions(model="default", out_dir=str(tmp_path / "auto")))
    d = res["trust"][ANIM]
    assert d["source"] == LIB
    assert {c["name"] for c in d["candidates"]} == {LIB, "tween-bandai-v5.3", "tween-bandai-delta-v3"}
    scores = {c["name"]: c["score"] for c in d["candidates"]}
    assert scores[LIB] > scores["tween-bandai-v5.3"]
    assert d["library"]["gaps"] and any(g["weight"] > 0 for g in d["library"]["gaps"])
    stage = Usd.Stage.Open(res["layer"])
    anim = stage.GetPrimAtPath(FILLED)
    assert anim.GetAttribute(tokens.LIBRARY_GAPS).Get() is not None
    # What filled it is named, not the network it was asked for (before: tween-bandai-v5.3).
    lib_hash = next(c["hash"] for c in d["candidates"] if c["name"] == LIB)
    assert anim.GetAttribute(tokens.MODEL).Get() == LIB
    assert anim.GetAttribute(tokens.MODEL_HASH).Get() == lib_hash
    # The network alone probes nothing beside it.
    alone = fill_shot(str(shot), FillOptions(model="default", trust="model", out_dir=str(tmp_path / "net")))
    assert not alone["trust"][ANIM].get("candidates") and LIB not in alone["licence"]


def test_a_walk_of_the_training_studio_stays_the_networks(tmp_path):
    """An eval-split walk of the studio the network was trained on (familiarity 1)."""
    shot = bandai_shot(tmp_path / "walk.usda", frames=91, keys_every=10)
    res = fill_shot(str(shot), FillOptions(model="default", out_dir=str(tmp_path / "out")))
    d = res["trust"][ANIM]
    # Keys as familiar as its training data keep the network: the library is not even probed.
    assert d["familiarity"] == 1.0 and d["choice"] == "model" and not d["candidates"]
    assert "nothing probed beside it" in d["reason"]


@pytest.mark.parametrize("every", [10, 30])
def test_the_batched_windows_choose_as_the_fill_does(every):
    """trusted_fill_windows with the library beside the network: per shot the in-betweener
    TrustedInbetweener decides on, and its fill, shot for shot."""
    net = load_inbetweener("default")
    lib = LibraryInbetweener(str(net.library_folder))
    spline = SplineInbetweener(net.skeleton)
    walk = model_take(BANDAI_CLIP, 30.0)  # the network's kind of motion
    cmu = model_take(CMU_CLIP, 30.0)  # a take the library holds
    T = 91
    rots = np.stack([walk.rotations[:T], cmu.rotations[:T]]).astype(np.float32)
    roots = np.stack([walk.root_positions[:T], cmu.root_positions[:T]]).astype(np.float32)
    keys = np.r_[np.arange(0, T - 1, every), T - 1]
    f = trusted_fill_windows(net, spline, rots, roots, keys, alternatives=(lib,))
    assert list(f.chosen) == [0, 1]
    for i in range(2):
        one = TrustedInbetweener(net, spline, alternatives=(lib,))
        got = one.fill(Motion(net.skeleton, rots[i], roots[i], 30.0), keys)
        assert f.decisions[i].source == one.last_decision.source
        assert f.decisions[i].score == pytest.approx(one.last_decision.score, abs=1e-6)
        np.testing.assert_allclose(f.decided[1][i], got.root_positions, atol=1e-4)
        np.testing.assert_allclose(np.abs((f.decided[0][i] * got.rotations).sum(-1)), 1.0, atol=1e-4)


def test_pick_ranks_a_score_before_none_and_the_primary_by_its_margin():
    assert pick([0.1, 0.2]) == 1 and pick([0.1, 0.2], margin=0.15) == 0
    assert pick([None, -0.5]) == 1 and pick([None, None]) == 0 and pick([0.3, 0.3]) == 0
    # With a floor an alternative must beat the spline (score above 0) as well as the primary.
    assert pick([-2.0, 0.0], floor=0.0) == 0 and pick([-2.0, 0.01], floor=0.0) == 1
    assert pick([None, 0.0], floor=0.0) == 0 and pick([None, 0.2], floor=0.0) == 1


@pytest.mark.parametrize("damaged, size", [("library/features.bin", 1000), ("delta/generator.onnx", 100_000)])
def test_a_broken_file_shipped_beside_the_network_is_one_line_and_nothing_written(
    tmp_path, monkeypatch, damaged, size
):
    """A model folder whose library (a truncated array) or delta network (a truncated ONNX
    file) is damaged is refused in one line naming the file, before anything is written, even
    for a walk that would probe neither; the user's shot is untouched."""
    import shutil

    from pipeline.errors import TweenError
    from pipeline.fill import api

    root = tmp_path / "models"
    folder = root / "default"
    shutil.copytree(
        load_inbetweener("default").folder, folder, ignore=shutil.ignore_patterns("torch", "bench")
    )
    with open(folder / damaged, "r+b") as f:
        f.truncate(size)
    monkeypatch.setenv("TWEEN_MODELS", str(root))
    monkeypatch.setattr(api, "_MODELS", {})
    shot = bandai_shot(tmp_path / "walk.usda", frames=61, keys_every=10)
    before = shot.read_bytes()
    out = tmp_path / "out"
    with pytest.raises(TweenError) as ei:
        fill_shot(str(shot), FillOptions(model="default", out_dir=str(out)))
    msg = str(ei.value)
    assert msg.startswith(str(folder / damaged)) and "\n" not in msg, msg
    assert shot.read_bytes() == before and not (out.exists() and any(out.iterdir()))


def test_the_commercial_library_model_fills_with_no_network(tmp_path):
    """``--model cmu-library`` (kind motion-library): the library alone, trusted against the
    spline; only the CMU terms reach the fill, and its folder says it may be used commercially."""
    from pipeline.infer.api import folder_kind
    from pipeline.library.model import LibraryModel

    folder = load_inbetweener("default").folder.parent / "cmu-library"
    meta = json.loads((folder / "model.json").read_text())
    assert folder_kind(folder) == "motion-library" and meta["commercial"] is True
    assert all("NC" not in s["licence"].split() for s in meta["sources"])
    assert isinstance(load_inbetweener("cmu-library"), LibraryModel)
    shot = cmu_shot(tmp_path / "cc.usda", frames=121, keys_every=12)
    res = fill_shot(str(shot), FillOptions(model="cmu-library", out_dir=str(tmp_path / "out")))
    assert res["licence"] == {"cmu-library-v1": meta["licence"]} and res["model"] == "cmu-library-v1"
    d = res["trust"][ANIM]
    assert not d["candidates"] and d["library"]["gaps"]  # nothing probed beside it; its gaps recorded


@pytest.mark.parametrize(
    "change, says",
    [
        ({"kind": "motion-library", "library": 3}, "'library' must name the library's folder"),
        (
            {"kind": "motion-library", "library": "../default/library"},
            "must be a folder inside the model folder",
        ),
        ({"kind": "motion-library", "name": ""}, "'name' must be a non-empty string"),
    ],
)
def test_a_broken_library_model_is_one_line_naming_its_json(tmp_path, change, says):
    from pipeline.infer.folder import ModelFolderError
    from pipeline.library.model import LibraryModel

    src = load_inbetweener("default").folder.parent / "cmu-library"
    folder = tmp_path / "lib-model"
    folder.mkdir()
    (folder / "library").symlink_to(src / "library")
    meta = json.loads((src / "model.json").read_text()) | change
    (folder / "model.json").write_text(json.dumps(meta))
    with pytest.raises(ModelFolderError) as ei:
        LibraryModel(folder)
    assert str(ei.value).startswith(f"{folder / 'model.json'}: ") and says in str(ei.value)


def test_a_library_model_whose_library_changed_is_refused(tmp_path):
    from pipeline.infer.folder import ModelFolderError
    from pipeline.library.model import LibraryModel

    src = load_inbetweener("default").folder.parent / "cmu-library"
    folder = tmp_path / "lib-model"
    folder.mkdir()
    (folder / "library").symlink_to(src / "library")
    meta = json.loads((src / "model.json").read_text()) | {"hash": "library-0000000000000000"}
    (folder / "model.json").write_text(json.dumps(meta))
    with pytest.raises(ModelFolderError, match="its library is 'library-059fec1137a3c46d'"):
        LibraryModel(folder)


@given(
    scores=st.lists(st.one_of(st.none(), st.floats(-5, 5)), min_size=1, max_size=4),
    margin=st.floats(0, 1),
    floor=st.one_of(st.none(), st.just(0.0)),
)
def test_pick_by_generation(scores, margin, floor):
    """The pick is one of the shots' in-betweeners; an alternative it picks has a score, beats
    the floor, and beats the primary's score by the margin; a larger margin never takes the
    shot from the primary."""
    i = pick(scores, margin, floor)
    assert 0 <= i < len(scores)
    if i > 0:
        assert scores[i] is not None and (floor is None or scores[i] > floor)
        assert scores[0] is None or scores[i] >= scores[0] + margin
    if i == 0:
        assert pick(scores, margin + 0.5, floor) == 0
