"""The burn-ins say what filled each in-between frame of a library fill."""

import numpy as np

from render.overlays import BurnIn, fill_sources, source_at


def test_each_gap_is_named_by_what_filled_it():
    facts = {"model": "library:studio", "library_gaps": [(1001, 1011), (1011, 1021), (1021, 1031)],
             "library_share": [1.0, 0.0, 0.4]}  # fmt: skip
    src = fill_sources(facts)
    assert [source_at(src, t) for t in (1005, 1015, 1025, 1011, 1040)] == [
        "library", "spline", "library 40%", None, None
    ]  # fmt: skip
    assert fill_sources({"model": "tween-bandai-v5.3"}) == []


def test_the_label_is_burnt_into_in_between_frames_only():
    facts = {"model": "library:studio", "library_gaps": [(1001, 1011)], "library_share": [1.0]}
    burn = BurnIn((640, 360), "sh010", facts, 24.0)
    mid = slice(640 // 2 - 40, 640 // 2 + 40)

    def bottom(frame, key):
        img = np.zeros((360, 640, 3), np.uint8)
        burn.apply(img, frame, key)
        return img[-burn.band :, mid].astype(int)

    plain = BurnIn((640, 360), "sh010", {"model": "library:studio"}, 24.0)
    ref = np.zeros((360, 640, 3), np.uint8)
    plain.apply(ref, 1005, False)
    assert np.abs(bottom(1005, False) - ref[-burn.band :, mid]).sum() > 0  # "library" written
    out = np.zeros((360, 640, 3), np.uint8)
    burn.apply(out, 1020, False)  # outside every gap: as without a library
    assert np.array_equal(out[-burn.band :, mid], ref[-burn.band :, mid])


def test_a_network_fill_names_the_model_the_spline_or_their_blend():
    facts = {
        "model": "tween-bandai-v5.3",
        "trust_gaps": [(1, 11), (11, 21)],
        "trust_gap_weights": [1.0, 0.25],
    }
    src = fill_sources(facts)
    assert [source_at(src, t) for t in (5, 15)] == ["model", "model 25%"]
    # A library fill's own gaps win over the trusted fill's.
    both = dict(facts, library_gaps=[(1, 11), (11, 21)], library_share=[0.0, 1.0])
    assert [source_at(fill_sources(both), t) for t in (5, 15)] == ["spline", "library"]


def test_the_layer_records_what_filled_each_gap(tmp_path):
    from pxr import Usd
    from usd_fixtures import FILLED, bandai_shot

    from pipeline.fill.api import FillOptions, fill_shot
    from usd_schemas import tokens

    shot = bandai_shot(tmp_path / "sh.usda", frames=41, keys_every=10)
    res = fill_shot(str(shot), FillOptions(out_dir=str(tmp_path / "o")))
    d = next(iter(res["trust"].values()))
    stage = Usd.Stage.Open(res["layer"])
    anim = stage.GetPrimAtPath(FILLED)
    gaps = [tuple(g) for g in anim.GetAttribute(tokens.TRUST_GAPS).Get()]
    weights = list(anim.GetAttribute(tokens.TRUST_GAP_WEIGHTS).Get())
    assert gaps == [tuple(g["times"]) for g in d["gap_weights"]] and len(gaps) == 4
    assert weights == [g["weight"] for g in d["gap_weights"]]
    assert all(0.0 <= w <= 1.0 for w in weights)


def test_a_network_shipped_beside_is_named_where_the_probes_chose_it():
    import json

    from render.overlays import decided_label

    facts = {"model": "tween-bandai-v5.3", "trust_gaps": [(1, 11), (11, 21)], "trust_gap_weights": [1.0, 0.25],
             "trust_evidence": json.dumps({"source": "tween-bandai-delta-v2", "choice": "blend"})}  # fmt: skip
    assert [source_at(fill_sources(facts), t) for t in (5, 15)] == ["delta-v2", "delta-v2 25%"]
    own = dict(facts, trust_evidence=json.dumps({"source": "tween-bandai-v5.3"}))
    assert decided_label(own) == "model" and decided_label({"model": "m"}) == "model"
    # Evidence of another shape, or a network sharing no prefix (beside a studio's library).
    for ev in ("not json", json.dumps([1]), json.dumps({"source": 3})):
        assert decided_label(dict(facts, trust_evidence=ev)) == "model"
    assert (
        decided_label(
            {"model": "library:studio", "trust_evidence": json.dumps({"source": "tween-bandai-v5.3"})}
        )
        == "model"
    )


def test_burn_ins_fit_the_smallest_frames_the_cli_accepts():
    """--size takes even sides from 16: the KEY badge (four font widths) and the panels' labels
    were wider or taller than such frames (a broadcast error, exit 1). What fits is drawn."""
    facts = {"model": "m", "trust_gaps": [[0, 10]], "trust_gap_weights": [0.5]}
    for w, h in ((16, 16), (32, 16), (16, 540), (40, 16)):
        for labels in (None, ["fill", "spline"]):
            burn = BurnIn((w, h), "sh010", facts, 30.0, panel_labels=labels)
            for frame, key in ((0, True), (5, False)):
                for channels in (3, 4):
                    img = np.full((h, w, channels), 77, np.uint8)
                    burn.apply(img, frame, key)
                    assert img.shape == (h, w, channels) and (img[..., :3] != 77).any()
