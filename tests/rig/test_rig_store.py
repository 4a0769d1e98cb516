"""The per-rig model store: reading rig.json, matching skeletons, the refusal hint."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.errors import TweenError
from pipeline.rig import store

NAMES = ("Root", "Spine", "Head", "Tail", "FrontLeg", "FrontFoot", "BackLeg", "BackFoot")
PARENTS = [-1, 0, 1, 0, 1, 4, 0, 6]
OFFSETS = np.array(
    [[0, 60, 0], [0, 5, 30], [0, 10, 20], [0, 0, -25], [8, -10, 5], [0, -30, 0], [8, -10, -5], [0, -30, 0]],
    np.float64,
)


def write_rig(folder, names=NAMES, parents=PARENTS, offsets=OFFSETS, mpu=0.01, up="Y", name=None, **extra):
    folder.mkdir(parents=True, exist_ok=True)
    meta = {
        "kind": "rig",
        "name": name or folder.name,
        "hash": f"hash-{folder.name}",
        "fps": 30.0,
        "skeleton": {
            "names": list(names),
            "parents": list(parents),
            "offsets": np.asarray(offsets).tolist(),
            "up_axis": up,
            "meters_per_unit": mpu,
        },
        "contact_joints": ["FrontFoot", "BackFoot"],
        "source": "test",
        "licence": "test",
        **extra,
    }
    (folder / "rig.json").write_text(json.dumps(meta))
    return folder


def lengths_m(offsets=OFFSETS, mpu=0.01):
    return np.linalg.norm(offsets, axis=-1) * mpu


def test_exact_skeleton_is_found(tmp_path):
    write_rig(tmp_path / "creature")
    (tmp_path / "default").mkdir()  # a human model folder (model.json) is not a rig model
    (tmp_path / "default" / "model.json").write_text("{}")
    assert store.find_rig_model(NAMES, PARENTS, lengths_m(), root=tmp_path) == tmp_path / "creature"
    info, perm = store.find_rig(NAMES, PARENTS, lengths_m(), root=tmp_path)
    assert info.name == "creature" and perm.tolist() == list(range(8))


def test_joint_order_may_differ_but_not_the_hierarchy(tmp_path):
    write_rig(tmp_path / "creature")
    order = [0, 3, 6, 7, 1, 2, 4, 5]  # still parent before child
    names = [NAMES[i] for i in order]
    inv = {old: new for new, old in enumerate(order)}
    parents = [-1 if PARENTS[i] < 0 else inv[PARENTS[i]] for i in order]
    info, perm = store.find_rig(names, parents, lengths_m(OFFSETS[order]), root=tmp_path)
    assert [names[i] for i in perm] == list(NAMES)
    # Same names, one joint re-parented: no match, and the reason says which.
    bad = list(PARENTS)
    bad[5] = 0
    assert store.find_rig_model(NAMES, bad, lengths_m(), root=tmp_path) is None
    perm, why = store.match_rig(store.read_rig_json(tmp_path / "creature"), NAMES, bad, lengths_m())
    assert perm is None and "'FrontFoot' has parent 'Root'" in why
    # A renamed joint, or one joint more.
    assert store.find_rig_model(NAMES[:-1] + ("BackToe",), PARENTS, lengths_m(), root=tmp_path) is None
    assert store.find_rig_model(NAMES + ("X",), PARENTS + [7], np.r_[lengths_m(), 0.1], root=tmp_path) is None


def test_bone_length_tolerance_and_units(tmp_path):
    write_rig(tmp_path / "creature")
    near = lengths_m() * np.r_[1, 1.04, 0.97, 1, 1, 1.03, 1, 1]
    assert store.find_rig_model(NAMES, PARENTS, near, root=tmp_path) is not None
    far = lengths_m().copy()
    far[5] *= 1.10
    assert store.find_rig_model(NAMES, PARENTS, far, root=tmp_path) is None
    perm, why = store.match_rig(store.read_rig_json(tmp_path / "creature"), NAMES, PARENTS, far)
    assert "bone 'FrontFoot'" in why and "10 % off" in why
    # The root offset is a rest position, not a bone: it is not compared.
    moved = lengths_m().copy()
    moved[0] *= 3
    assert store.find_rig_model(NAMES, PARENTS, moved, root=tmp_path) is not None
    # A model stored in metres matches the same rig measured in a centimetre shot.
    write_rig(tmp_path / "metres", offsets=OFFSETS / 100, mpu=1.0)
    found = {p.name for p in [store.find_rig_model(NAMES, PARENTS, lengths_m(), root=tmp_path)]}
    assert found <= {"creature", "metres"}
    (tmp_path / "creature" / "rig.json").unlink()
    assert store.find_rig_model(NAMES, PARENTS, lengths_m(), root=tmp_path) == tmp_path / "metres"
    # Twice the size is another rig.
    assert store.find_rig_model(NAMES, PARENTS, 2 * lengths_m(), root=tmp_path) is None


def test_best_fit_wins(tmp_path):
    write_rig(tmp_path / "a_close", offsets=OFFSETS * 1.03)
    write_rig(tmp_path / "b_exact")
    assert store.find_rig_model(NAMES, PARENTS, lengths_m(), root=tmp_path).name == "b_exact"
    assert store.find_rig_model(NAMES, PARENTS, lengths_m() * 1.03, root=tmp_path).name == "a_close"


def test_broken_rig_json_is_skipped_in_the_store_and_an_error_when_named(tmp_path, capsys):
    write_rig(tmp_path / "good")
    bad = tmp_path / "broken"
    bad.mkdir()
    (bad / "rig.json").write_text("{not json")
    nokind = write_rig(tmp_path / "nokind")
    meta = json.loads((nokind / "rig.json").read_text())
    meta["kind"] = "human"
    (nokind / "rig.json").write_text(json.dumps(meta))
    assert [i.name for i in store.rig_models(tmp_path)] == ["good"]
    err = capsys.readouterr().err
    assert "broken/rig.json" in err and "nokind/rig.json" in err
    for folder, match in ((bad, "cannot read"), (nokind, '"kind" is not "rig"')):
        with pytest.raises(TweenError) as ei:
            store.read_rig_json(folder)
        assert str(folder / "rig.json") in str(ei.value) and match in str(ei.value)
        assert "\n" not in str(ei.value)
    missing = write_rig(tmp_path / "missing")
    meta = json.loads((missing / "rig.json").read_text())
    del meta["skeleton"]["parents"]
    (missing / "rig.json").write_text(json.dumps(meta))
    with pytest.raises(TweenError, match="missing 'parents'"):
        store.read_rig_json(missing)
    write_rig(tmp_path / "cycle", parents=[-1, 0, 1, 0, 1, 4, 0, 9])
    with pytest.raises(TweenError, match="parent-before-child"):
        store.read_rig_json(tmp_path / "cycle")


def test_store_root_is_the_models_root(tmp_path, monkeypatch):
    monkeypatch.setenv("TWEEN_MODELS", str(tmp_path))
    write_rig(tmp_path / "creature")
    assert store.models_root() == tmp_path
    assert store.find_rig_model(NAMES, PARENTS, lengths_m()) == tmp_path / "creature"
    hint = store.no_model_hint("shots/sh010.usdc", "/Root/Skel", ["mixamorig_Hips"] * 27)
    assert hint == (
        f"/Root/Skel (27 joints, root mixamorig_Hips) matches no human mapping and no rig model in "
        f"{tmp_path}/; train one with: tween train-rig shots/sh010.usdc --skeleton /Root/Skel "
        f"--out {tmp_path}/sh010"
    )
