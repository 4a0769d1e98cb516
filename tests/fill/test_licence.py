"""Every fill names the licence of what filled it (issue 30, item 4): each shipped model declares
its training sources and licence, and the fill's JSON, its layer and the published take carry it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from pxr import Sdf, Usd
from usd_fixtures import FILLED, bandai_shot

from pipeline.fill.api import FillOptions, fill_shot
from pipeline.fill.licence import NO_WEIGHTS, NOT_STATED, folder_licence, model_licence
from pipeline.infer.folder import ModelFolderError
from pipeline.usd import dailies
from usd_schemas import tokens

ROOT = Path(__file__).resolve().parents[2]
MODELS = sorted(p for p in (ROOT / "models").iterdir() if p.is_dir())


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    return bandai_shot(tmp_path_factory.mktemp("walk") / "walk.usda", frames=41, keys_every=10)


@pytest.mark.parametrize("folder", MODELS, ids=[p.name for p in MODELS])
def test_every_shipped_model_declares_its_sources_and_licence(folder):
    meta = json.loads(
        next(p for p in (folder / "model.json", folder / "rig.json") if p.is_file()).read_text()
    )
    assert isinstance(meta["licence"], str) and meta["licence"] not in ("", NOT_STATED)
    assert isinstance(meta["commercial"], bool) and meta["sources"]
    for src in meta["sources"]:
        assert src["name"] and src["licence"] and src["use"]
    # A model made from any non-commercial capture (trained on it, or fine-tuned from a model that
    # was) is itself non-commercial: a fine-tune inherits its init's terms.
    if any("NC" in src["licence"].split() or "BY-NC" in src["licence"] for src in meta["sources"]):
        assert "NC" in meta["licence"] and meta["commercial"] is False
    if any(src["use"].startswith("inherited") for src in meta["sources"]):
        assert meta["commercial"] is False


def test_the_licence_of_a_folder_a_builtin_and_a_bad_one(tmp_path):
    assert model_licence("default") == "CC BY-NC 4.0"
    assert model_licence("interp") == NO_WEIGHTS and model_licence("spline") == NO_WEIGHTS
    assert folder_licence(ROOT / "models" / "elephant", "rig.json") == "CC BY-SA 4.0"
    (tmp_path / "model.json").write_text(json.dumps({"name": "old"}))
    assert folder_licence(tmp_path) == NOT_STATED  # a model exported before licences
    (tmp_path / "model.json").write_text(json.dumps({"name": "bad", "licence": 3}))
    with pytest.raises(ModelFolderError, match=r"model\.json: 'licence' must be"):
        folder_licence(tmp_path)


def test_a_fill_names_its_models_licence_in_json_layer_and_published_take(walk, tmp_path):
    out = tmp_path / "out"
    res = fill_shot(str(walk), FillOptions(model="default", out_dir=str(out)))
    # The network, and the library and delta network it ships beside it (probed on the shot's
    # keys with it).
    cmu = json.loads((ROOT / "models" / "default" / "library" / "library.json").read_text())["licence"]
    delta = json.loads((ROOT / "models" / "default" / "delta" / "model.json").read_text())["licence"]
    want = {
        "tween-bandai-v5.3": "CC BY-NC 4.0",
        "library:cmu-subjects-1-3": cmu,
        "tween-bandai-delta-v3": delta,
    }
    assert res["licence"] == want and cmu.startswith("CMU Graphics Lab")
    layer = Sdf.Layer.FindOrOpen(res["layer"])
    assert dict(layer.customLayerData["tween"]["licence"]) == want
    stage = Usd.Stage.Open(res["layer"])
    assert (
        stage.GetPrimAtPath(FILLED).GetAttribute(tokens.MODEL_LICENCE).Get()
        == f"tween-bandai-v5.3: CC BY-NC 4.0; library:cmu-subjects-1-3: {cmu}; tween-bandai-delta-v3: {delta}"
    )
    # The network alone (--trust model) probes nothing beside it: its licence only.
    alone = fill_shot(str(walk), FillOptions(model="default", trust="model", out_dir=str(tmp_path / "alone")))
    assert alone["licence"] == {"tween-bandai-v5.3": "CC BY-NC 4.0"}
    # Approved and published, the plain layer still says under which terms it was made.
    dailies.approve(str(walk), 0, out_dir=str(out), by="alice")
    pub = dailies.publish(str(walk), out_dir=str(out))
    player = Sdf.Layer.FindOrOpen(pub["layer"])
    assert dict(player.customLayerData["tween"]["licence"]) == want
    pstage = Usd.Stage.Open(pub["layer"])
    assert (
        pstage.GetPrimAtPath(pub["animations"][0]).GetAttribute(tokens.MODEL_LICENCE).Get()
        == f"tween-bandai-v5.3: CC BY-NC 4.0; library:cmu-subjects-1-3: {cmu}; tween-bandai-delta-v3: {delta}"
    )


def test_fill_local_json_names_the_licence_and_a_builtin_has_none(walk, tmp_path):
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "fill-local", str(walk), "--model", "interp",
                        "--out-dir", str(tmp_path)], capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert res["licence"] == {"interpolation": NO_WEIGHTS}
    stage = Usd.Stage.Open(res["layer"])
    assert (
        stage.GetPrimAtPath(FILLED).GetAttribute(tokens.MODEL_LICENCE).Get() == f"interpolation: {NO_WEIGHTS}"
    )
