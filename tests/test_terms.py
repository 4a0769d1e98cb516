"""The one rule for a model folder's ``commercial`` (pipeline.data.terms)."""

import pytest

from pipeline.data.terms import commercial

CMU = "CMU Graphics Lab terms: any use, commercial products included; not resold as data"


@pytest.mark.parametrize(
    "licences, expected",
    [
        (["CC BY 4.0"], True),
        (["CC0 1.0", "MIT", CMU], True),
        (["CC BY-SA 4.0 (share alike, credit required)"], True),
        (["CC BY-NC 4.0"], False),
        ([CMU, "CC BY-NC 4.0"], False),  # one non-commercial source rules the model out
        (["CC BY-ND 4.0"], False),  # weights are a derivative
        (["research only"], False),
        (["Non-commercial use"], False),
        (["not stated (the studio's own takes)"], False),
        (["unknown (set --licence)"], False),  # train-rig's guess when the clip says nothing
        ([], False),
    ],
)
def test_commercial_only_where_every_source_allows_it(licences, expected):
    assert commercial(licences) is expected
