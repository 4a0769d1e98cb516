"""Model families are declared (issue 18): one registry loads a model by the kind its
model.json / rig.json names; in-betweeners declare their capabilities; no caller duck-types."""

from __future__ import annotations

import ast
import inspect
import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import TweenError
from pipeline.infer import api
from pipeline.infer.api import (
    Capabilities,
    Inbetweener,
    folder_kind,
    kinds,
    load_model,
    register,
    rig_kinds,
    unregister,
)
from pipeline.infer.generator_onnx import OnnxInbetweener
from pipeline.infer.interp import InterpolationInbetweener
from pipeline.infer.spline import SplineInbetweener
from pipeline.rig.infer import RigInbetweener

REPO = Path(__file__).resolve().parents[2]
MODELS = REPO / "models"


def shipped_folders() -> list[tuple[Path, str]]:
    out = []
    for p in sorted(MODELS.iterdir()):
        for file in ("model.json", "rig.json"):
            if (p / file).is_file():
                out.append((p, file))
                break
    return out


@pytest.fixture(autouse=True)
def _shipped_models_root(monkeypatch):
    monkeypatch.delenv("TWEEN_MODELS", raising=False)


@pytest.fixture
def registered():
    """Kinds a test registers are forgotten afterwards."""
    added: list[str] = []
    yield added
    for kind in added:
        unregister(kind)


def test_every_shipped_model_folder_declares_its_kind_and_loads_by_it():
    folders = shipped_folders()
    assert {p.name for p, _ in folders} >= {"default", "dna", "elephant"}
    from pipeline.library.model import LibraryModel

    want = {
        "generator-onnx": OnnxInbetweener,
        "motion-library": LibraryModel,
        "rig-ganimator-onnx": RigInbetweener,
    }
    for folder, file in folders:
        meta = json.loads((folder / file).read_text())
        assert meta.get("kind") in kinds(file), (folder, meta.get("kind"))  # written out, not defaulted
        assert folder_kind(folder, file) == meta["kind"]
        # The kind is the one key added to the shipped files: first, as exports write it.
        assert (folder / file).read_text().startswith(f'{{\n "kind": "{meta["kind"]}",\n "name": ')
        for name in (folder, folder.name):  # a folder, or a name under the models root
            inb = load_model(name)
            assert isinstance(inb, Inbetweener) and isinstance(inb, want[meta["kind"]])
            assert inb.model_hash == meta["hash"] and inb.name == meta["name"]
    assert type(load_model("interp")) is InterpolationInbetweener
    assert type(load_model("interpolation")) is InterpolationInbetweener
    assert type(load_model("spline")) is SplineInbetweener
    assert api.load_inbetweener is load_model  # the name callers used before the registry


def test_built_in_kinds_and_names():
    assert {"interpolation", "spline", "generator-onnx", "rig-ganimator-onnx"} <= set(kinds())
    assert set(kinds(None)) >= {"interpolation", "spline"}
    assert rig_kinds() == ("rig", "rig-ganimator-onnx")  # "rig": rig.json files written before kinds
    assert set(api.builtin_names()) == {"interp", "interpolation", "spline"}


def test_capabilities_of_each_built_in():
    interp, spline = load_model("interp"), load_model("spline")
    default, dna, elephant = load_model("default"), load_model("dna"), load_model("elephant")
    assert interp.capabilities == Capabilities(partial_keys=False, dna=False, batch=False, any_rig=True)
    assert spline.capabilities == Capabilities(partial_keys=False, dna=False, batch=True, any_rig=True)
    # The shipped networks keep their own kind of motion from what is probed beside them.
    for model, takes_dna in ((default, False), (dna, True)):
        shipped = dict(
            partial_keys=True, batch=True, any_rig=False, novelty=True, probe_margin=0.25, keeps_own=True
        )
        assert model.capabilities == Capabilities(dna=takes_dna, **shipped)
    # The pose bank is per folder too: the delta model ships none (docs/trust.md).
    assert load_model("models/delta").capabilities.novelty is False
    assert default.pose_bank is not None
    assert elephant.capabilities == Capabilities(partial_keys=False, dna=False, batch=False, any_rig=False)
    # Declared on the class (the DNA encoder is a per-folder setting of the ONNX generator).
    for cls in (InterpolationInbetweener, SplineInbetweener, OnnxInbetweener, RigInbetweener):
        assert isinstance(cls.__dict__["capabilities"], Capabilities)
    assert default.has_dna is False and dna.has_dna is True
    with pytest.raises(AttributeError):  # frozen
        interp.capabilities.batch = True


def test_protocol_fill_declares_the_keyword_arguments_every_in_betweener_takes():
    for fill in (
        Inbetweener.fill,
        InterpolationInbetweener.fill,
        SplineInbetweener.fill,
        OnnxInbetweener.fill,
        RigInbetweener.fill,
    ):
        params = inspect.signature(fill).parameters
        assert list(params)[:4] == ["self", "motion", "keys", "seed"], fill.__qualname__
        for kw in ("joint_keys", "dna"):
            assert params[kw].default is None, (fill.__qualname__, kw)


def test_extras_an_in_betweener_does_not_declare_are_refused():
    from pipeline.data.skeletons import bandai_skeleton
    from pipeline.motion.clip import Motion

    sk = bandai_skeleton()
    T, J = 12, len(sk)
    rot = np.zeros((T, J, 4), np.float32)
    rot[..., 0] = 1
    m = Motion(sk, rot, np.zeros((T, 3), np.float32), 30.0)
    keys = np.array([0, 11])
    mask = np.ones((2, J + 1), bool)
    for inb in (load_model("interp"), load_model("spline")):
        assert np.array_equal(inb.fill(m, keys).rotations, inb.fill(m, keys, 0, None, None).rotations)
        with pytest.raises(ValueError, match="partial keys"):
            inb.fill(m, keys, joint_keys=mask)
        with pytest.raises(ValueError, match="motion DNA"):
            inb.fill(m, keys, dna=m)


def _copy_model(src: Path, dst: Path, **changes) -> Path:
    """``src`` with its ONNX files and pose bank linked and its JSON changed."""
    dst.mkdir(parents=True)
    for f in src.iterdir():
        if f.suffix in (".onnx", ".npz") or f.name in ("library", "delta"):
            (dst / f.name).symlink_to(f)
    file = "rig.json" if (src / "rig.json").exists() else "model.json"
    meta = json.loads((src / file).read_text())
    meta.update(changes)
    for k in [k for k, v in changes.items() if v is None]:
        del meta[k]
    (dst / file).write_text(json.dumps(meta))
    return dst


def test_unknown_kind_is_one_line_naming_the_file(tmp_path):
    folder = _copy_model(MODELS / "default", tmp_path / "future", kind="transformer-onnx")
    for name in (folder, str(folder)):
        with pytest.raises(TweenError) as ei:
            load_model(name)
        msg = str(ei.value)
        assert msg.startswith(str(folder / "model.json") + ":") and "\n" not in msg
        assert "unknown kind 'transformer-onnx'" in msg and "generator-onnx" in msg
    # A rig kind in a model.json is no model.json kind.
    wrong = _copy_model(MODELS / "default", tmp_path / "wrong", kind="rig-ganimator-onnx")
    with pytest.raises(TweenError, match="model.json: unknown kind 'rig-ganimator-onnx'"):
        load_model(wrong)
    # Not a string.
    bad = _copy_model(MODELS / "default", tmp_path / "bad", kind=3)
    with pytest.raises(TweenError, match=r"model.json: 'kind' must be a string"):
        load_model(bad)
    # rig.json: the store names the file too.
    rig = _copy_model(MODELS / "elephant", tmp_path / "rigx", kind="rig-diffusion")
    with pytest.raises(TweenError) as ei:
        load_model(rig)
    assert str(rig / "rig.json") in str(ei.value) and "rig-ganimator-onnx" in str(ei.value)
    assert "\n" not in str(ei.value)


def test_a_model_json_without_kind_is_the_onnx_generator(tmp_path):
    """Models exported before kinds existed load as they did."""
    old = _copy_model(MODELS / "default", tmp_path / "old", kind=None)
    assert "kind" not in json.loads((old / "model.json").read_text())
    assert folder_kind(old) == "generator-onnx"
    inb = load_model(old)
    assert type(inb) is OnnxInbetweener and inb.model_hash == load_model("default").model_hash
    legacy = _copy_model(MODELS / "elephant", tmp_path / "legacy", kind="rig")  # rig.json before kinds
    assert type(load_model(legacy)) is RigInbetweener


def test_kind_is_not_part_of_the_model_hash():
    from pipeline.infer.folder import HASHED_SETTINGS, model_hash

    assert "kind" not in HASHED_SETTINGS
    for name in ("default", "dna"):
        meta = json.loads((MODELS / name / "model.json").read_text())
        assert model_hash(MODELS / name, meta) == meta["hash"]
        assert model_hash(MODELS / name, {k: v for k, v in meta.items() if k != "kind"}) == meta["hash"]


class EchoInbetweener:
    """A new architecture as a test registers it: holds the first key."""

    capabilities = Capabilities(any_rig=True)
    model_hash = "echo"
    fps = 30.0

    def __init__(self, folder):
        self.folder = folder
        self.name = "echo" if folder is None else json.loads((folder / "model.json").read_text())["name"]
        from pipeline.data.skeletons import bandai_skeleton

        self.skeleton = bandai_skeleton()

    def fill(self, motion, keys, seed=0, joint_keys=None, dna=None):
        return motion


def test_a_kind_registered_here_is_loaded_by_load_model(tmp_path, monkeypatch, registered):
    folder = tmp_path / "models" / "echo-v1"
    folder.mkdir(parents=True)
    (folder / "model.json").write_text(json.dumps({"kind": "test-echo", "name": "echo-v1"}))
    with pytest.raises(TweenError, match="unknown kind 'test-echo'"):
        load_model(folder)
    register("test-echo", EchoInbetweener)
    registered.append("test-echo")
    inb = load_model(folder)
    assert type(inb) is EchoInbetweener and inb.folder == folder and inb.name == "echo-v1"
    assert isinstance(inb, Inbetweener)
    monkeypatch.setenv("TWEEN_MODELS", str(tmp_path / "models"))
    assert load_model("echo-v1").folder == tmp_path / "models" / "echo-v1"  # by name, under the root
    # A kind that needs no folder, under a name of its own.
    register("test-hold", EchoInbetweener, file=None, names=("hold",))
    registered.append("test-hold")
    assert load_model("hold").folder is None and load_model("test-hold").name == "echo"
    # The farm's fill loads it the same way.
    from pipeline.fill import api as fill

    fill._MODELS.clear()
    try:
        assert type(fill._model("echo-v1")) is EchoInbetweener
        assert type(fill._model("hold")) is EchoInbetweener and fill.rig_folder("hold") is None
    finally:
        fill._MODELS.clear()


def test_a_rig_kind_registered_here_is_a_rig_model_to_the_store(tmp_path, registered):
    from pipeline.rig.store import read_rig_json, rig_models

    rig = _copy_model(MODELS / "elephant", tmp_path / "root" / "quad", kind="test-rig-net")
    with pytest.raises(TweenError, match="not a rig model"):
        read_rig_json(rig)
    register("test-rig-net", lambda folder: ("quad", folder), file="rig.json")
    registered.append("test-rig-net")
    assert read_rig_json(rig).name == "elephant" and [i.folder for i in rig_models(rig.parent)] == [rig]
    assert load_model(rig) == ("quad", rig)


# -- no duck typing --------------------------------------------------------------------------
INBETWEENER_CLASSES = (InterpolationInbetweener, SplineInbetweener, OnnxInbetweener, RigInbetweener)
#: Everything an in-betweener class defines beyond the data every one has (name, hash, fps,
#: skeleton): methods and declared properties a caller might probe for.
PROBED = {n for cls in INBETWEENER_CLASSES for n in vars(cls) if not n.startswith("__")} - {
    "name",
    "model_hash",
    "fps",
    "skeleton",
}


def _sources():
    for top in ("pipeline", "workers"):
        for path in sorted((REPO / top).rglob("*.py")):
            yield path, ast.parse(path.read_text(), str(path))


def test_no_caller_probes_an_in_betweener_with_hasattr_or_getattr():
    assert {"fill_batch", "has_dna", "capabilities", "fill", "synthesize"} <= PROBED
    hits = []
    for path, tree in _sources():
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Name)
                and node.func.id in ("hasattr", "getattr")
                and len(node.args) >= 2
                and isinstance(node.args[1], ast.Constant)
                and node.args[1].value in PROBED
            ):
                hits.append(
                    f"{path.relative_to(REPO)}:{node.lineno}: {node.func.id}(…, {node.args[1].value!r})"
                )
            # has_dna stays for scripts and notebooks; the pipeline reads capabilities.dna.
            if isinstance(node, ast.Attribute) and node.attr == "has_dna" and isinstance(node.ctx, ast.Load):
                hits.append(f"{path.relative_to(REPO)}:{node.lineno}: .has_dna")
    assert not hits, "capabilities found by duck typing:\n" + "\n".join(hits)


def test_fill_and_bench_load_through_the_registry_only():
    """fill.py, bench/methods.py and usd/solve.py name no concrete family."""
    names = {cls.__name__ for cls in INBETWEENER_CLASSES}
    for rel in ("pipeline/fill/api.py", "pipeline/bench/methods.py", "pipeline/fill/solve.py"):
        tree = ast.parse((REPO / rel).read_text())
        used = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
        used |= {a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names}
        assert not used & names, (rel, used & names)
        assert "load_inbetweener" not in (REPO / rel).read_text(), rel


def test_experimental_models_are_said_at_every_fill_and_keep_their_hash(tmp_path):
    """models/README.md's experimental models carry why in model.json; a fill with one says it
    in one stderr line and its JSON; the flag is no part of the model hash."""
    import subprocess
    import sys

    from pipeline.infer.folder import experimental

    flagged = {p.parent.name for p in MODELS.glob("*/model.json") if experimental(p.parent.name)}
    assert flagged == {"cmu-s123"}  # delta ships beside the default (model.json "beside")
    assert experimental("default") is None and experimental("interp") is None
    readme = (MODELS / "README.md").read_text()
    assert all(f"`{name}/` |" in readme and "**experimental**" in readme for name in flagged)
    try:
        from pipeline.train.export import model_hash
    except ImportError:  # no torch: the hash is checked where training is installed
        model_hash = None
    if model_hash is not None:
        for name in flagged:
            meta = json.loads((MODELS / name / "model.json").read_text())
            assert model_hash(MODELS / name, meta) == meta["hash"]
    shot = Path(__file__).resolve().parents[2] / "examples" / "sh010_walk.usda"
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "fill-local", str(shot), "--model", "cmu-s123",
                        "--out-dir", str(tmp_path)], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    warned = [ln for ln in r.stderr.splitlines() if ln.startswith("tween: warning:")]
    assert warned == [
        f"tween: warning: --model cmu-s123 is experimental ({experimental('cmu-s123')}); not for production shots"
    ]
    assert json.loads(r.stdout)["experimental"] == experimental("cmu-s123")


def test_a_models_setting_without_the_default_is_said_not_silent(tmp_path, monkeypatch, capsys):
    """A TWEEN_MODELS typo swapped the shipped network for interpolation with nothing said:
    not a folder is refused naming the setting; a folder without ``default`` (rig models
    only, say) fills humans by interpolation and says so."""
    monkeypatch.setenv("TWEEN_MODELS", str(tmp_path / "modles"))
    with pytest.raises(TweenError, match=r"TWEEN_MODELS .*modles: not a folder of models"):
        load_model("default")
    (tmp_path / "rigs").mkdir()
    monkeypatch.setenv("TWEEN_MODELS", str(tmp_path / "rigs"))
    assert isinstance(load_model("default"), InterpolationInbetweener)
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"tween: warning: TWEEN_MODELS {tmp_path / 'rigs'} holds no default model (a folder "
                   "'default' with model.json): human characters are filled by interpolation"]  # fmt: skip
    monkeypatch.delenv("TWEEN_MODELS")
    assert isinstance(load_model("default"), OnnxInbetweener)  # the shipped one


@pytest.mark.parametrize("value", ["abc", "", "1.5", "0", "-1", "99999999999999999999", "٣"])
def test_a_bad_ort_threads_setting_is_named_not_the_model_file(value, monkeypatch, tmp_path, capsys):
    """TWEEN_ORT_THREADS=abc was said as "generator.onnx: onnxruntime cannot load it", and 0
    or -1 were taken."""
    from usd_fixtures import bandai_shot

    from pipeline.cli import main

    monkeypatch.setenv("TWEEN_ORT_THREADS", value)
    shot = bandai_shot(tmp_path / "s.usda", frames=21, keys_every=10)
    with pytest.raises(SystemExit) as e:
        main(["fill-local", str(shot), "--out-dir", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert (
        e.value.code == 2
        and len(err) == 1
        and f"TWEEN_ORT_THREADS={value!r}: must be a whole number" in err[0]
    )
    assert not (tmp_path / "out").exists()


def test_an_empty_cache_setting_is_the_default_not_the_working_folder():
    from pipeline.data.cache_paths import cache_root

    assert cache_root({"TWEEN_CACHE": ""}) == cache_root({}) != Path("")
