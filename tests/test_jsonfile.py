"""JSON a person wrote: a key given twice is refused, naming the key and its line."""

import json
import subprocess
import sys

import pytest
from hypothesis import given
from hypothesis import strategies as st

from pipeline import jsonfile


def test_a_key_twice_names_the_key_and_the_line_of_the_second():
    text = '{\n "Hips": "pelvis",\n "Spine": "spine_01",\n "Hips": "root"\n}\n'
    with pytest.raises(jsonfile.DuplicateKeyError, match=r"key 'Hips' given twice \(line 4\)"):
        jsonfile.loads(text)
    with pytest.raises(jsonfile.DuplicateKeyError, match="'b' given twice"):
        jsonfile.loads('{"a": {"b": 1, "b": 2}}')  # nested objects too
    assert jsonfile.loads('{"a": [1, {"a": 2}]}') == {"a": [1, {"a": 2}]}  # one key per object


@given(st.recursive(st.none() | st.booleans() | st.integers() | st.text(max_size=5),
                    lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=5), c, max_size=3),
                    max_leaves=10))  # fmt: skip
def test_json_without_duplicates_reads_as_json_does(value):
    text = json.dumps(value, indent=1)
    assert jsonfile.loads(text) == json.loads(text)


def test_a_mapping_file_with_a_key_twice_is_one_line(tmp_path):
    from usd_fixtures import bandai_shot

    shot = bandai_shot(tmp_path / "sh.usda", frames=21)
    mapping = tmp_path / "map.json"
    mapping.write_text('{\n "Hips": "Hips",\n "Hips": "Spine"\n}\n')
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "fill-local", str(shot), "--mapping", str(mapping),
                        "--out-dir", str(tmp_path / "o")], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 2 and r.stderr.count("\n") == 1
    assert f"mapping file {mapping}: key 'Hips' given twice (line 3)" in r.stderr
    assert not (tmp_path / "o").exists()


def test_a_mapping_that_is_a_pipe_or_a_folder_is_refused_not_waited_on(tmp_path):
    """A named pipe with no writer: reading it blocked the fill forever."""
    import os

    from usd_fixtures import bandai_shot

    shot = bandai_shot(tmp_path / "sh.usda", frames=21)
    os.mkfifo(tmp_path / "map.json")
    (tmp_path / "folder.json").mkdir()
    for odd in (tmp_path / "map.json", tmp_path / "folder.json"):
        r = subprocess.run([sys.executable, "-m", "pipeline.cli", "fill-local", str(shot), "--mapping", str(odd),
                            "--out-dir", str(tmp_path / "o")], capture_output=True, text=True, timeout=120)  # fmt: skip
        assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
        says = "a folder, not a mapping file" if odd.is_dir() else "not a regular file"
        assert f"mapping file {odd}: {says}" in r.stderr and not (tmp_path / "o").exists()


def test_json_nested_too_deeply_is_a_value_error_naming_the_file(tmp_path):
    """Before: a RecursionError (an internal error) from json's reader."""
    deep = "[" * 100_000 + "]" * 100_000
    with pytest.raises(jsonfile.TooDeepError, match="not valid JSON: arrays or objects nested too deeply"):
        jsonfile.loads(deep)
    assert isinstance(jsonfile.TooDeepError(), ValueError)  # what every caller catches and names
    from pipeline.library.store import open_library

    lib = tmp_path / "lib"
    lib.mkdir()
    (lib / "library.json").write_text(deep)
    with pytest.raises(Exception) as e:
        open_library(lib)
    assert (
        str(e.value)
        == f"{lib / 'library.json'}: cannot read: not valid JSON: arrays or objects nested too deeply to read"
    )
