"""`tween fill --library`: a shot filled from a studio's library through the product's path,
with the library's version and per-gap decision in the layer; bad libraries refused in one line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from library_fixtures import CMU_TAKE, HELD_OUT
from pxr import Usd
from usd_fixtures import ANIM, FILLED, samples, tree_hashes

from pipeline.errors import TweenError
from pipeline.fill.api import FillOptions, fill_shot
from pipeline.library.store import MANIFEST, LibraryError, open_library
from pipeline.motion.bvh import read_bvh
from pipeline.usd.convert import write_shot
from usd_schemas import tokens


@pytest.fixture(scope="module")
def cmu_shot(data_dir, tmp_path_factory):
    """The library's CMU take (another actor and rig than the network's), blocked every 10."""
    folder = tmp_path_factory.mktemp("cmushot")
    m = read_bvh(data_dir / "cmu_iclone" / CMU_TAKE)
    return write_shot(m, folder / "sh030_cmu.usda", fps=30, keys_every=10)


@pytest.fixture(scope="module")
def shot(data_dir, tmp_path_factory):
    """A held-out take of a motion the library holds, converted and blocked every 10 frames."""
    folder = tmp_path_factory.mktemp("shot")
    m = read_bvh(data_dir / "bandai_namco" / "dataset-2" / HELD_OUT).slice(0, 81)
    return write_shot(m, folder / "sh020_walk.usda", keys_every=10)


def _run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "pipeline.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd)  # fmt: skip


def test_a_library_fill_records_the_library_and_each_gap(cmu_shot, library, tmp_path):
    shot = cmu_shot
    before = tree_hashes(Path(shot).parent)
    r = _run("fill-local", shot, "--library", library, "--out-dir", tmp_path / "out")
    assert r.returncode == 0, r.stderr
    assert tree_hashes(Path(shot).parent) == before  # the user's files are never modified
    res = json.loads(r.stdout)
    lib = open_library(library)
    assert res["model"] == "library:studio" and res["model_hash"] == f"library-{lib.hash}"
    d = res["trust"][ANIM]
    gaps = d["library"]["gaps"]
    # The network (which never saw this actor) was probed too; the library decided.
    assert d["source"] == "library:studio" and [c["name"] for c in d["candidates"]][0] == "library:studio"
    assert len(d["candidates"]) == 2 and "decided on library:studio by the probes" in r.stderr
    assert d["library"]["hash"] == lib.hash and len(gaps) == len(keyed_times(shot)) - 1
    k = keyed_times(shot)
    assert [g["times"] for g in gaps] == [[a, b] for a, b in zip(k[:-1], k[1:], strict=True)]
    assert all(0.0 <= g["share"] <= 1.0 and g["share"] == pytest.approx(g["weight"] * g["trust_weight"], abs=1e-3)
               for g in gaps)  # fmt: skip
    assert "library studio:" in r.stderr and "gap(s) from its takes" in r.stderr
    # In the layer: the library's name, version and each gap's share.
    stage = Usd.Stage.Open(res["layer"])
    anim = stage.GetPrimAtPath(FILLED)
    assert anim.GetAttribute(tokens.LIBRARY_HASH).Get() == lib.hash
    assert "studio" in anim.GetAttribute(tokens.LIBRARY).Get()
    assert list(anim.GetAttribute(tokens.LIBRARY_SHARE).Get()) == pytest.approx([g["share"] for g in gaps])
    assert len(anim.GetAttribute(tokens.LIBRARY_GAPS).Get()) == len(gaps)
    # The keys carry the animator's values, bit for bit.
    keyed = samples(Usd.Stage.Open(str(shot)), ANIM)
    filled = samples(Usd.Stage.Open(res["layer"]), FILLED)
    for t, v in keyed.items():
        assert np.array_equal(filled[t], v)


def keyed_times(shot) -> list[float]:
    return sorted(samples(Usd.Stage.Open(str(shot)), ANIM))


def test_where_the_network_knows_the_motion_better_it_decides(shot, library, tmp_path):
    """A take of the network's own training capture: its probes beat the library's."""
    res = fill_shot(str(shot), FillOptions(library=str(library), out_dir=str(tmp_path / "o")))
    d = res["trust"][ANIM]
    names = [c["name"] for c in d["candidates"]]
    assert names[0] == "library:studio" and d["source"] == names[1] != names[0]
    scores = {c["name"]: c["score"] for c in d["candidates"]}
    assert scores[d["source"]] > scores["library:studio"]
    assert "library" not in d  # no gap of it came from the library


def test_the_library_moves_the_frames_between_the_keys_toward_the_take(shot, library, tmp_path, data_dir):
    """Scored as the library bench scores (the rig's world joint positions between the keys):
    the library's fill is nearer the capture than the spline through the same keys."""
    from pipeline.bench.studio import review_positions

    truth = read_bvh(data_dir / "bandai_namco" / "dataset-2" / HELD_OUT).slice(0, 81)
    want = truth.positions() * truth.skeleton.meters_per_unit * 100.0
    inside = np.setdiff1d(np.arange(81), np.arange(0, 81, 10))
    miss = {}
    for name, opts in (("lib", {"library": str(library), "trust": "model"}), ("spline", {"model": "spline"})):
        res = fill_shot(str(shot), FillOptions(out_dir=str(tmp_path / name), **opts))
        pos = review_positions(res["review"], 81)
        miss[name] = float(np.linalg.norm(pos[inside] - want[inside], axis=-1).mean())
    assert miss["lib"] < 0.8 * miss["spline"]


@pytest.mark.parametrize(
    "make, says",
    [
        (lambda p: p, "no such library folder"),
        (lambda p: (p.mkdir(), p)[1], "not a library"),
    ],
)
def test_a_missing_or_foreign_library_is_one_line_and_writes_nothing(shot, tmp_path, make, says):
    lib = make(tmp_path / "lib")
    out = tmp_path / "out"
    r = _run("fill-local", shot, "--library", lib, "--out-dir", out)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert r.stderr.startswith("tween: error:") and str(lib) in r.stderr and says in r.stderr
    assert not out.exists()


@pytest.mark.parametrize("model", ["interp", "spline"])
def test_a_library_fill_probes_a_network_not_a_curve(shot, library, tmp_path, model):
    with pytest.raises(TweenError, match=f"--library .*--model {model} is no network"):
        fill_shot(str(shot), FillOptions(library=str(library), model=model, out_dir=str(tmp_path / "o")))
    assert not (tmp_path / "o").exists()
    # Through the farm's command, refused before any farm starts: one line, exit 2.
    r = _run("fill", shot, "--library", library, "--model", model, "--out-dir", tmp_path / "o")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and f"--model {model} is no network" in r.stderr
    assert not (tmp_path / "o").exists()


def test_a_library_fill_probes_the_network_model_names(cmu_shot, library, tmp_path):
    """A studio's own network (here the delta model, as a fine-tune from it would be) is what
    --model names beside --library: probed on the keys instead of the default, named on stderr
    and with its licence in the fill's JSON."""
    r = _run(
        "fill-local", cmu_shot, "--library", library, "--model", "models/delta", "--out-dir", tmp_path / "o"
    )
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    d = res["trust"][ANIM]
    names = [c["name"] for c in d["candidates"]]
    delta = json.loads(Path("models/delta/model.json").read_text())["name"]
    assert (
        names == ["library:studio", delta] and f"with the human network {delta} probed beside it" in r.stderr
    )
    assert res["licence"][delta] == json.loads(Path("models/delta/model.json").read_text())["licence"]


def test_the_farms_library_setting_is_every_jobs_default(library, monkeypatch, tmp_path):
    from workers.cli import _opts

    monkeypatch.setenv("TWEEN_FARM_CONFIG", os.devnull)
    monkeypatch.setenv("TWEEN_LIBRARY", str(library))
    assert _opts(FillOptions())["library"] == os.path.abspath(library)
    # A job that asks for a curve gets it: the farm's library is no network's to probe beside.
    assert not _opts(FillOptions(model="spline")).get("library")
    assert _opts(FillOptions(model="models/delta"))["library"] == os.path.abspath(library)
    own = tmp_path / "own"
    assert _opts(FillOptions(library=str(own)))["library"] == str(own)  # a job's own wins
    monkeypatch.delenv("TWEEN_LIBRARY")
    (tmp_path / "farm.toml").write_text(f'library = "{library}"\n')
    monkeypatch.setenv("TWEEN_FARM_CONFIG", str(tmp_path / "farm.toml"))
    assert _opts(FillOptions())["library"] == os.path.abspath(library)
    # A job that asks for a curve gets it: the farm's library is no network's to probe beside.
    assert not _opts(FillOptions(model="spline")).get("library")
    assert _opts(FillOptions(model="models/delta"))["library"] == os.path.abspath(library)


def test_a_library_outside_the_shot_roots_is_refused(shot, library, tmp_path):
    from workers import paths

    roots = [str(Path(shot).parent)]
    with pytest.raises(paths.PathRefused, match="library resolves to"):
        paths.check_job(str(shot), {"library": str(library)}, roots)
    paths.check_job(str(shot), {"library": str(library)}, [*roots, str(library)])


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    manifest=st.one_of(
        st.binary(max_size=64),
        st.dictionaries(
            st.sampled_from(["kind", "version", "frames", "takes", "fps", "skeleton", "hash"]),
            st.one_of(
                st.none(),
                st.integers(-3, 10**9),
                st.text(max_size=8),
                st.lists(st.integers(), max_size=3),
                st.just("tween-library"),
                st.just(1),
            ),  # fmt: skip
            max_size=7,
        ),
    )
)
def test_any_broken_manifest_is_a_library_error(tmp_path_factory, manifest):
    folder = tmp_path_factory.mktemp("lib")
    data = manifest if isinstance(manifest, bytes) else json.dumps(manifest).encode()
    (folder / MANIFEST).write_bytes(data)
    try:
        from pipeline.library.infer import LibraryInbetweener

        LibraryInbetweener(folder)
    except LibraryError as e:
        assert "\n" not in str(e) and str(folder) in str(e)


def test_a_24_fps_shot_is_filled_on_its_keys_times(library, tmp_path, data_dir):
    """At 24 fps, keys every 10 frames are 12.5 model frames apart and are filled at the
    nearer model frame: the fill is read back gap by gap so that its keys fall on theirs
    (pipeline.fill.solve.model_time). A shot of a take the library holds comes back within
    1 cm of the capture (0.7 cm measured; 1.4 cm when the fill was read at the rate alone,
    half a model frame off every other key; 0.06 cm at 30 fps, where keys are on frames)."""
    from pipeline.bench.studio import resample, review_positions

    take = read_bvh(data_dir / "bandai_namco" / "dataset-2" / "dataset-2_walk_active_001.bvh.gz").slice(
        0, 101
    )
    at24 = resample(take, 24.0)
    T = len(at24)
    want = at24.positions() * at24.skeleton.meters_per_unit * 100.0
    shot = write_shot(take, tmp_path / "sh040_walk24.usda", fps=24, keys_every=10)
    inside = np.setdiff1d(np.arange(T), np.r_[np.arange(0, T, 10), T - 1])
    res = fill_shot(
        str(shot), FillOptions(out_dir=str(tmp_path / "out"), library=str(library), trust="model")
    )
    miss = np.linalg.norm(review_positions(res["review"], T)[inside] - want[inside], axis=-1).mean()
    assert miss < 1.0, miss


def test_a_farm_library_setting_that_is_no_library_names_the_setting(tmp_path, monkeypatch):
    """`tween fill` said only "/abs/path: no such library folder", a folder the user never
    typed (it came from TWEEN_LIBRARY or the farm config); now the line names the setting."""
    from pipeline.errors import TweenError
    from workers.cli import _opts

    monkeypatch.setenv("TWEEN_FARM_CONFIG", os.devnull)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("TWEEN_LIBRARY", "nolib")
    with pytest.raises(TweenError) as e:
        _opts(FillOptions())
    line = str(e.value)
    assert line.startswith(
        f"library {tmp_path / 'nolib'} (the farm's setting: TWEEN_LIBRARY or the farm config's `library`): "
    )
    assert "no such library folder" in line and "\n" not in line
    assert not _opts(FillOptions(model="spline")).get("library")  # a curve never opens it
