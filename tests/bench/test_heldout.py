"""The held-out CMU source of the bench, whole or by subject (`--source cmu:5,6,7`)."""

import pytest

from pipeline.bench.heldout import cmu_files, parse_source
from pipeline.errors import TweenError


def test_a_subject_list_picks_those_subjects_takes(data_dir):
    assert parse_source("cmu") == ("cmu", None) and parse_source("eval") == ("eval", None)
    assert parse_source("cmu:7,5,6,5") == ("cmu", (5, 6, 7))
    every = cmu_files()
    some = cmu_files((5, 6, 7))
    assert some and set(some) < set(every)
    assert {f.name[:3] for f in some} == {"005", "006", "007"}
    assert {f.name[:3] for f in every} - {f.name[:3] for f in some} == {"001", "002", "003"}


@pytest.mark.parametrize("bad", ["cmu:", "cmu:five", "eval:1"])
def test_a_bad_source_is_one_clear_line(bad, capsys):
    with pytest.raises(TweenError, match="source"):
        parse_source(bad)
    from pipeline.cli import main

    with pytest.raises(SystemExit) as ex:
        main(["bench", "--source", bad, "--methods", "interp"])
    err = capsys.readouterr().err.strip().splitlines()
    assert ex.value.code == 2 and len(err) == 1 and bad in err[0]


def test_a_subject_with_no_takes_is_named(data_dir):
    with pytest.raises(FileNotFoundError, match="subjects 4"):
        cmu_files((4,))
