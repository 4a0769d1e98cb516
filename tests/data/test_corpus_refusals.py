"""A corpus that cannot be trained as described is refused before anything is read or written,
in one line naming the corpus file and the source: terms that forbid a shipped model (issue 30's
data rule), weights that are no normal numbers, two sources of the same clips, a source that
yields no frame, a mapping file that cannot be read, and top-level keys of the wrong type."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from cli_contract import refused

from pipeline.data.corpus import CorpusError, load_corpus, prepare
from pipeline.data.terms import commercial, forbids_training
from pipeline.train.corpus import prepared, read_clip
from pipeline.usd.take import take_files

CMU = ("001_01.bvh.gz", "002_02.bvh.gz")
CMU_TERMS = "CMU Graphics Lab Motion Capture Database terms (free for all uses, commercial products included)"


@pytest.fixture(scope="module")
def takes(data_dir, tmp_path_factory) -> Path:
    """A folder ``cmu`` of two real takes and a folder ``bad`` whose every file is unreadable."""
    root = tmp_path_factory.mktemp("takes")
    (root / "cmu").mkdir()
    for name in CMU:
        shutil.copy(data_dir / "cmu_iclone" / name, root / "cmu" / name)
    (root / "bad").mkdir()
    (root / "bad" / "a.bvh").write_text("not a BVH\n")
    (root / "bad" / "b.bvh").write_text("HIERARCHY\nROOT Hips\n{\n")
    return root


def _corpus(root: Path, *sources: str, head: str = 'name = "c"\n') -> Path:
    """A corpus file in ``root`` of ``sources`` (the body of each [[source]] table)."""
    path = root / "corpus.toml"
    path.write_text(head + "".join(f"[[source]]\n{s}\n" for s in sources))
    return path


def _src(name: str, path: str = "cmu", licence: str = "CC0", extra: str = "") -> str:
    return f'name = "{name}"\npath = "{path}"\nlicence = "{licence}"\n{extra}'


def _refused(path: Path, *says: str) -> str:
    with pytest.raises(CorpusError) as e:
        load_corpus(path)
    line = str(e.value)
    assert "\n" not in line and str(path) in line, line
    assert all(s in line for s in says), line
    return line


@pytest.mark.parametrize(
    "licence, forbids",
    [
        ("research only", True),
        ("CC BY-NC-ND 4.0 (no derivatives)", True),
        ("CC BY-ND 4.0", True),
        ("Attribution-NonCommercial-NoDerivatives 4.0 International", True),
        ("for research purposes only", True),
        ("academic use only", True),
        ("not for training", True),
        ("No AI training", True),
        ("CC BY-NC 4.0", False),  # trains; the weights are non-commercial (terms.commercial)
        ("CC BY-NC-SA 4.0", False),
        ("CC0 1.0", False),
        ("CC BY 4.0", False),
        ("MIT", False),
        (CMU_TERMS + "; not to be resold as data, even converted", False),
        ("studio-internal", False),
    ],
)
def test_terms_that_forbid_training_a_shipped_model(licence, forbids):
    assert bool(forbids_training(licence)) is forbids
    if not forbids and "NC" in licence:
        assert commercial([licence]) is False  # allowed to train, but not commercial weights


@pytest.mark.parametrize("licence", ["research only", "CC BY-NC-ND 4.0 (no derivatives)"])
def test_a_source_whose_terms_forbid_training_is_refused(takes, tmp_path, licence):
    root = tmp_path / "r"
    shutil.copytree(takes, root)
    path = _corpus(root, _src("ok", licence="CC BY-NC 4.0"), _src("banned", path="bad", licence=licence))
    _refused(path, "banned", licence, "does not allow training")


def test_training_on_a_banned_source_writes_nothing(takes, tmp_path, capsys, monkeypatch):
    pytest.importorskip("torch")
    monkeypatch.setenv("TWEEN_CACHE", str(tmp_path / "cache"))
    root = tmp_path / "r"
    shutil.copytree(takes, root)
    path = _corpus(root, _src("cmu", licence="research only"))
    run = ["train", "--corpus", path, "--steps", "4", "--path-steps", "0", "--batch", "2", "--lengths", "64"]
    line = refused([*run, "--out", tmp_path / "run"], capsys, tmp_path)
    assert str(path) in line and "cmu" in line and "research only" in line


def test_shipped_corpora_still_load():
    for path in sorted(Path("pipeline/data/corpora").glob("*.toml")):
        corpus = load_corpus(path)
        assert all(not forbids_training(s.licence) for s in corpus.sources)


@pytest.mark.parametrize("weight", ["1e-320", "1e-7", "0", "1e7", "inf", "nan"])
def test_weights_that_are_no_normal_share_are_refused(takes, tmp_path, weight):
    root = tmp_path / "r"
    shutil.copytree(takes, root)
    extra = f"weight = {weight}\ninclude = "
    path = _corpus(root, _src("a", extra=extra + '"001_*"'), _src("b", extra=extra + '"002_*"'))
    _refused(path, "source 1 (a)", "'weight' must be a positive number")


def test_weights_at_the_bounds_load(takes, tmp_path):
    root = tmp_path / "r"
    shutil.copytree(takes, root)
    path = _corpus(
        root,
        _src("a", extra='weight = 1e-6\ninclude = "001_*"'),
        _src("b", extra='weight = 1e6\ninclude = "002_*"'),
    )
    assert [s.weight for s in load_corpus(path).sources] == [1e-6, 1e6]


def test_two_sources_of_the_same_clips_are_refused(takes, tmp_path):
    root = tmp_path / "r"
    shutil.copytree(takes, root)
    same = _corpus(root, _src("cmu", extra='include = "001_*"'), _src("cmu_again", extra='include = "001_*"'))
    _refused(same, "'cmu' and 'cmu_again'", "count twice")
    # Described otherwise but holding a file in common: refused before anything is written.
    overlap = _corpus(root, _src("cmu", extra='include = "001_*"'), _src("all", path="./cmu"))
    corpus = load_corpus(overlap)
    with pytest.raises(CorpusError, match=r"sources 'cmu' and 'all' both hold .*001_01\.bvh\.gz") as e:
        prepare(corpus, tmp_path / "c", read_clip, take_files, progress=False)
    assert str(overlap) in str(e.value) and not (tmp_path / "c").exists()


def test_a_source_that_yields_no_frame_is_one_error_and_no_cache(takes, tmp_path, capsys):
    root = tmp_path / "r"
    shutil.copytree(takes, root)
    path = _corpus(root, _src("cmu", extra="weight = 0.1"), _src("bad", path="bad", extra="weight = 0.9"))
    with pytest.raises(CorpusError) as e:
        prepare(load_corpus(path), tmp_path / "c", read_clip, take_files, progress=False)
    line = str(e.value)
    assert str(path) in line and "source 'bad'" in line and "weight 0.9 cannot be honoured" in line
    assert "none of its 2 file(s) could be read" in line and "\n" not in line
    assert capsys.readouterr().err == ""  # no "skipped clip" line per file before it
    assert not (tmp_path / "c").exists()  # no half-made cache entry


def test_a_source_that_yields_no_frame_refuses_training(takes, tmp_path, capsys, monkeypatch):
    pytest.importorskip("torch")
    monkeypatch.setenv("TWEEN_CACHE", str(tmp_path / "cache"))
    root = tmp_path / "r"
    shutil.copytree(takes, root)
    path = _corpus(root, _src("cmu", extra="weight = 0.1"), _src("bad", path="bad", extra="weight = 0.9"))
    run = ["train", "--corpus", path, "--steps", "4", "--path-steps", "0", "--batch", "2", "--lengths", "64"]
    line = refused([*run, "--out", tmp_path / "run"], capsys, tmp_path)
    assert str(path) in line and "source 'bad'" in line


def test_a_mapping_file_that_cannot_be_read_is_one_error_before_any_clip(takes, tmp_path, capsys):
    root = tmp_path / "r"
    shutil.copytree(takes, root)
    (root / "rig.json").write_text('{"not"\n}')
    path = _corpus(root, _src("cmu", extra='mapping = "rig.json"'))
    with pytest.raises(CorpusError) as e:
        prepared(path, tmp_path / "c", progress=False)
    line = str(e.value)
    assert str(path) in line and "source 'cmu'" in line and str(root / "rig.json") in line
    assert "\n" not in line and capsys.readouterr().err == "" and not (tmp_path / "c").exists()
    (root / "rig.json").write_text('{"Hipz": "CC_Base_Hip"}')  # JSON, but no model joint
    with pytest.raises(CorpusError, match=r"source 'cmu': mapping file .*unknown model joint"):
        prepared(path, tmp_path / "c", progress=False)


@pytest.mark.parametrize(
    "head, says",
    [
        ("name = 5\n", "'name' must be a non-empty string"),
        ('name = ""\n', "'name' must be a non-empty string"),
        ('name = ["a"]\n', "'name' must be a non-empty string"),
        ('fps = "30"\n', "'fps' must be a number"),
        ("fps = nan\n", "'fps' must be a number"),
    ],
)
def test_top_level_keys_of_the_wrong_type_are_refused(takes, tmp_path, head, says):
    root = tmp_path / "r"
    shutil.copytree(takes, root)
    _refused(_corpus(root, _src("cmu"), head=head), says)
