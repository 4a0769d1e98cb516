"""Reading real shots made by other tools, and mapping rigs onto the model skeleton."""

import json

import numpy as np
import pytest
from usd_fixtures import CMU_CLIP, ELEPHANT, FIGURE, SIMPLE

from pipeline.adapt.mapping import MODEL_JOINTS, MappingError, map_joints
from pipeline.data.skeletons import bandai_skeleton
from pipeline.motion.bvh import read_bvh
from pipeline.usd.read import anim_values, read_shot


def _parents(tokens):
    return np.array([tokens.index(t.rsplit("/", 1)[0]) if "/" in t else -1 for t in tokens])


def test_elephant_two_skeletons_60fps_non_integer_times():
    shot = read_shot(ELEPHANT)
    assert shot.tcps == 60 and shot.meters_per_unit == 0.01
    assert len(shot.characters) == 2
    ele = next(c for c in shot.characters if c.skel_path.endswith("Elefant/_skel"))
    # Bound on the SkelRoot (inherited animationSource), resolved through UsdSkel.
    assert ele.anim_path.endswith("Elefant/_anim") and len(ele.joints) == 27
    assert len(ele.sample_times) == 3023 and ele.sample_times[-1] != int(ele.sample_times[-1])
    rot, tr, sc = anim_values(shot.stage, ele, ele.sample_times[:3])
    assert rot.shape == (3, 27, 4) and np.allclose(np.linalg.norm(rot, axis=-1), 1, atol=1e-3)


def test_usdz_assets_with_z_up_transforms():
    fig = read_shot(FIGURE)
    assert fig.tcps == 24 and len(fig.characters) == 1
    c = fig.characters[0]
    assert c.anim_path == "/RiggedFigure/Animations/skelAnim_0" and len(c.joints) == 19
    # The Z_UP xform above the skeleton is part of its world transform.
    assert not np.allclose(c.skel_to_world[:3, :3], np.eye(3))
    simple = read_shot(SIMPLE)
    assert simple.start == 1 and len(simple.characters[0].sample_times) == 50


def test_mapping_conventions():
    cc = read_bvh(CMU_CLIP).skeleton
    m = map_joints(cc.names, cc.parents)
    names = {k: cc.names[v] for k, v in m.items()}
    assert set(names) == set(MODEL_JOINTS)
    assert names["Chest"] == "CC_Base_Spine02" and names["UpperLeg_L"] == "CC_Base_L_Thigh"
    assert names["Hips"] == "CC_Base_Hip" and names["Hand_R"] == "CC_Base_R_Hand"
    b = bandai_skeleton()
    assert map_joints(b.names, b.parents) == {n: i for i, n in enumerate(b.names)}
    # Mixamo (both separators) and HumanIK names.
    base = ["Hips", "Hips/Spine", "Hips/Spine/Spine1", "Hips/Spine/Spine1/Spine2", "Hips/Spine/Spine1/Spine2/Neck",
            "Hips/Spine/Spine1/Spine2/Neck/Head"]  # fmt: skip
    for s in ("Left", "Right"):
        arm = f"Hips/Spine/Spine1/Spine2/{s}Shoulder"
        base += [arm, f"{arm}/{s}Arm", f"{arm}/{s}Arm/{s}ForeArm", f"{arm}/{s}Arm/{s}ForeArm/{s}Hand"]
        base += [f"Hips/{s}UpLeg", f"Hips/{s}UpLeg/{s}Leg", f"Hips/{s}UpLeg/{s}Leg/{s}Foot",
                 f"Hips/{s}UpLeg/{s}Leg/{s}Foot/{s}ToeBase"]  # fmt: skip
    for prefix in ("", "mixamorig:", "mixamorig_"):
        toks = ["/".join(prefix + p for p in t.split("/")) for t in base]
        m = map_joints(tuple(toks), _parents(toks))
        leaf = {k: toks[v].rsplit("/", 1)[-1] for k, v in m.items()}
        assert leaf["Chest"] == prefix + "Spine2" and leaf["Spine"] == prefix + "Spine"
        assert leaf["LowerLeg_L"] == prefix + "LeftLeg" and leaf["UpperArm_R"] == prefix + "RightArm"
        assert leaf["Toes_L"] == prefix + "LeftToeBase" and len(leaf) == 21


def test_mapping_override_file(tmp_path):
    shot = read_shot(FIGURE)
    c = shot.characters[0]
    with pytest.raises(MappingError, match="joints do not map"):
        map_joints(c.joints, c.parents)
    f = tmp_path / "map.json"
    f.write_text(json.dumps({"Hips": "torso_joint_1", "Head": "neck_joint_2", "UpperArm_L": "arm_joint_L_1",
                             "LowerArm_L": "arm_joint_L_2", "Hand_L": "arm_joint_L_3", "UpperArm_R": "arm_joint_R_1",
                             "LowerArm_R": "arm_joint_R_2", "Hand_R": "arm_joint_R_3", "UpperLeg_L": "leg_joint_L_1",
                             "LowerLeg_L": "leg_joint_L_2", "Foot_L": "leg_joint_L_3", "UpperLeg_R": "leg_joint_R_1",
                             "LowerLeg_R": "leg_joint_R_2", "Foot_R": "leg_joint_R_3"}))  # fmt: skip
    from pipeline.adapt.mapping import load_override

    m = map_joints(c.joints, c.parents, load_override(f))
    assert c.names[m["Chest"]] == "torso_joint_3" and c.names[m["Neck"]] == "neck_joint_1"
    f.write_text(json.dumps({"Pelvis": "x"}))
    with pytest.raises(MappingError, match="unknown model joint"):
        load_override(f)


def _figure_roles(tmp_path):
    f = tmp_path / "map.json"
    roles = {"Hips": "torso_joint_1", "Head": "neck_joint_2"}
    for s in "LR":
        roles.update({f"UpperArm_{s}": f"arm_joint_{s}_1", f"LowerArm_{s}": f"arm_joint_{s}_2",
                      f"Hand_{s}": f"arm_joint_{s}_3", f"UpperLeg_{s}": f"leg_joint_{s}_1",
                      f"LowerLeg_{s}": f"leg_joint_{s}_2", f"Foot_{s}": f"leg_joint_{s}_3"})  # fmt: skip
    f.write_text(json.dumps(roles))
    return f


def test_usdz_figure_fills_with_a_mapping_file_and_read_only_folder_is_refused(tmp_path):
    """The published folder is the test's own (a copy of the usdz in a 0o555 folder), never
    ../shared/data, whose permissions depend on the checkout. Tests run as root, which
    os.access() lets write anywhere; check_out_dir also refuses a folder whose mode bits
    allow no write, so the refusal holds for root too."""
    import os
    import shutil

    from pxr import Usd
    from usd_fixtures import samples, tree_hashes

    from pipeline.errors import ShotError
    from pipeline.fill.api import FillOptions, fill_shot

    f = _figure_roles(tmp_path)
    published = tmp_path / "published"
    published.mkdir()
    shot = published / FIGURE.name
    shutil.copyfile(FIGURE, shot)
    shared_before = tree_hashes(FIGURE.parent)
    os.chmod(published, 0o555)
    try:
        before = tree_hashes(published)
        with pytest.raises(ShotError, match="read-only"):  # published folder: never written, even as root
            fill_shot(str(shot), FillOptions(model="interp", mapping=str(f)))
        assert sorted(os.listdir(published)) == [FIGURE.name] and tree_hashes(published) == before
        res = fill_shot(str(shot), FillOptions(model="interp", mapping=str(f), out_dir=str(tmp_path / "o")))
        assert tree_hashes(published) == before
    finally:
        os.chmod(published, 0o755)
    assert tree_hashes(FIGURE.parent) == shared_before
    stage = Usd.Stage.Open(res["review"])
    assert stage.GetTimeCodesPerSecond() == 24
    anim = "/RiggedFigure/Animations/skelAnim_0"
    filled, orig = samples(stage, anim + "_tween"), samples(stage, anim)
    assert sorted(filled) == [float(t) for t in range(0, 31)]
    for t, v in orig.items():
        assert np.array_equal(filled[t], v)


def test_out_folder_os_access_refusal(tmp_path, monkeypatch):
    """A folder the user may not write (os.access says no: another owner, a read-only
    mount), mode bits notwithstanding; root cannot be made to fail os.access, so it is
    monkeypatched."""
    import os

    from pipeline.errors import ShotError
    from pipeline.usd import write

    shot = tmp_path / "shot.usda"
    assert write.check_out_dir(str(shot), str(tmp_path / "o")) == tmp_path / "o"
    real = os.access
    monkeypatch.setattr(write.os, "access", lambda p, mode, **kw: False if mode & os.W_OK else real(p, mode))
    with pytest.raises(ShotError, match="read-only"):
        write.check_out_dir(str(shot), str(tmp_path / "o" / "deeper"))
    assert not (tmp_path / "o").exists()
