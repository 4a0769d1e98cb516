"""Left/right mirroring: exact geometry on real clips, the stored Bandai table, augmentation and
test-time averaging wiring."""

import numpy as np
import pytest

from pipeline.data.cache import load_split
from pipeline.data.skeletons import FOOT_JOINTS, bandai_mirror, bandai_skeleton
from pipeline.motion.fk import fk
from pipeline.motion.mirror import derive_mirror, find_pairs
from pipeline.motion.skeleton import Skeleton


@pytest.fixture(scope="module")
def clips():
    return load_split("train", limit=30)


def test_pairs_from_names():
    names = ("Hips", "Leg_L", "Leg_R", "LeftHand", "RightHand", "Spine")
    assert find_pairs(names).tolist() == [0, 2, 1, 4, 3, 5]
    with pytest.raises(ValueError, match="pair up"):
        find_pairs(("x_L_l", "x_R_l", "x_L_r"))  # two rules disagree


def test_mirrored_positions_are_the_reflected_positions(clips):
    skel, m = bandai_skeleton(), bandai_mirror()
    rot, root = clips.clip(3)
    _, pos = fk(rot, root, skel.parents, skel.offsets)
    _, mpos = fk(m.rotations(rot, skel.parents), m.root(root), skel.parents, skel.offsets)
    want = pos[:, m.pairs] * np.array([1, 1, -1])
    # Bandai's rest offsets are symmetric to 0.04 cm, not exactly.
    assert np.abs(mpos - want).max() < 0.1
    assert np.abs(mpos - want).mean() < 0.02


def test_mirror_is_an_involution(clips):
    skel, m = bandai_skeleton(), bandai_mirror()
    rot, root = clips.clip(7)
    back = m.rotations(m.rotations(rot, skel.parents), skel.parents)
    assert np.allclose(np.abs((back * rot).sum(-1)), 1.0, atol=1e-6)
    assert np.allclose(m.root(m.root(root)), root)


def test_stored_bandai_mirror_is_what_the_data_derives(clips):
    skel = bandai_skeleton()
    derived = derive_mirror(skel, clips.rotations[::7])
    assert np.array_equal(derived.signs, bandai_mirror().signs)
    assert np.array_equal(derived.pairs, bandai_mirror().pairs)


def test_asymmetric_rig_is_refused():
    skel = Skeleton(
        ("Hips", "Leg_L", "Leg_R"),
        np.array([-1, 0, 0]),
        np.array([[0, 90, 0], [10, -5, 0], [10, 12, 0]], np.float32),
    )
    with pytest.raises(ValueError, match="mirror images"):
        derive_mirror(skel, np.tile([0, 0, 0, 1.0], (4, 3, 1)))


def test_contacts_swap_feet():
    skel, m = bandai_skeleton(), bandai_mirror()
    feet = [skel.index(n) for n in FOOT_JOINTS]  # Foot_L, Toes_L, Foot_R, Toes_R
    assert m.contacts(np.array([1.0, 2.0, 3.0, 4.0]), feet).tolist() == [3.0, 4.0, 1.0, 2.0]


def test_mirror_augmentation_keeps_windows_and_keys(clips):
    from pipeline.train.generator_training import TrainConfig, step_batch

    skel = bandai_skeleton()
    feet = [skel.index(n) for n in FOOT_JOINTS]
    plain = step_batch(TrainConfig(seed=2, batch=16), clips, skel, feet, 50)
    mirrored = step_batch(TrainConfig(seed=2, batch=16, mirror=0.5), clips, skel, feet, 50)
    assert plain["L"] == mirrored["L"] and np.array_equal(plain["keys"], mirrored["keys"])
    same = [bool((plain["crot"][i] == mirrored["crot"][i]).all()) for i in range(16)]
    assert 0 < sum(same) < 16  # some windows mirrored, the rest untouched
