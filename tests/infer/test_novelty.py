"""How familiar a shot's keys are (pipeline/infer/novelty.py): the nearest bank pose, found
quickly, is the one measuring every pose of the bank finds, bit for bit."""

from pathlib import Path

import numpy as np

from pipeline.data import posebank
from pipeline.data.posebank import pose_features
from pipeline.data.skeletons import bandai_skeleton
from pipeline.infer.novelty import nearest_cm, novelty_cm
from pipeline.usd.take import model_take, studio_take

ROOT = Path(__file__).resolve().parents[2]
SHOT = ROOT / "examples" / "sh010_walk.usda"
BANK = ROOT / "models" / "default" / "pose_bank.npz"


def _every_pose(features, bank, cm_per_unit=1.0):
    """The search as it was: every bank pose measured exactly, 16 poses at a time."""
    x, bank = np.asarray(features, np.float32), np.asarray(bank, np.float32)
    out = np.empty(len(x))
    for s in range(0, len(x), 16):
        out[s : s + 16] = np.linalg.norm(x[s : s + 16, None] - bank[None], axis=-1).mean(-1).min(1)
    return out * cm_per_unit


def test_the_nearest_pose_is_the_exhaustive_searchs_bit_for_bit(data_dir):
    """Every key's distance was measured against all 4,096 poses of the bank (0.39 s a take
    of 200 keys, for each take); a quick pass now picks the few to measure. On a familiar
    shot, a CMU take on its own rig, near-ties, exact copies of bank poses and values no pose
    holds, the distances are the exhaustive search's, bit for bit."""
    skel = bandai_skeleton()
    bank = posebank.load(BANK)
    shot = model_take(SHOT)
    cmu = studio_take(data_dir / "cmu_iclone" / "002_02.bvh.gz")
    k = np.linspace(0, len(cmu) - 1, 40).astype(int)
    rng = np.random.default_rng(0)
    poses = {
        "shot": pose_features(shot.rotations, shot.root_positions, skel),
        "cmu": pose_features(cmu.rotations[k], cmu.root_positions[k], skel),
        "near ties": bank[:40] + rng.normal(0, 1e-4, (40, *bank.shape[1:])).astype(np.float32),
        "copies": bank[100:110].copy(),
        "odd": np.stack([np.full(bank.shape[1:], np.nan), np.full(bank.shape[1:], 1e20), bank[0] * 1e-30]),
    }
    for what, x in poses.items():
        with np.errstate(all="ignore"):  # the odd poses' squares overflow, as they did
            got, want = nearest_cm(x, bank, 1.0), _every_pose(x, bank, 1.0)
        np.testing.assert_array_equal(got, want, err_msg=what)
    assert (_every_pose(poses["copies"], bank) == 0).all()
    assert nearest_cm(poses["shot"][:0], bank).shape == (0,)
    # And so the shot's novelty, as the trusted fill reads it (keys every 8th frame).
    keys = np.arange(0, len(shot), 8)
    rots, roots = shot.rotations[keys][None], shot.root_positions[keys][None]
    feats = pose_features(rots[0], roots[0], skel)
    assert novelty_cm(rots, roots, bank, skel)[0] == np.median(_every_pose(feats, bank, 1.0))


def test_a_takes_novelty_costs_a_fraction_of_the_exhaustive_search(data_dir):
    """256 keys (MAX_KEYS) of a CMU take against the bank: the exhaustive search took 0.5 s
    here, for every take of a fill. Timed against it under the same load, best of two: at
    least 4 times faster (about 11 measured)."""
    import time

    skel = bandai_skeleton()
    bank = posebank.load(BANK)
    cmu = studio_take(data_dir / "cmu_iclone" / "002_02.bvh.gz")
    k = np.linspace(0, len(cmu) - 1, 256).astype(int)
    x = pose_features(cmu.rotations[k], cmu.root_positions[k], skel)

    def best(f) -> float:
        times = []
        for _ in range(2):
            t0 = time.perf_counter()
            f(x, bank)
            times.append(time.perf_counter() - t0)
        return min(times)

    quick, every = best(nearest_cm), best(_every_pose)
    assert quick * 4 < every, (quick, every)
