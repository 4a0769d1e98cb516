"""`--joint-offsets`: a constant per-joint rotation per window (another actor's posture), drawn
from its own stream so that a run without it trains on the same batches bit for bit."""

import numpy as np
import pytest

pytest.importorskip("torch")

from scipy.spatial.transform import Rotation  # noqa: E402

from pipeline.data.cache import ClipSet  # noqa: E402
from pipeline.data.skeletons import FOOT_JOINTS, bandai_skeleton  # noqa: E402
from pipeline.motion.augment import joint_offsets  # noqa: E402
from pipeline.motion.rotations import quat_inv, quat_mul  # noqa: E402
from pipeline.train.generator_training import TrainConfig, step_batch  # noqa: E402


def _offsets(rot: np.ndarray, out: np.ndarray) -> np.ndarray:
    """rot⁻¹ · out per frame and joint, w >= 0: the right-multiplied offset."""
    off = quat_mul(quat_inv(rot.astype(np.float64)), out.astype(np.float64))
    return np.where(off[..., 3:] < 0, -off, off)


def _angles_deg(off: np.ndarray) -> np.ndarray:
    return np.degrees(2 * np.arccos(np.clip(off[..., 3], -1, 1)))


def test_offsets_are_constant_over_the_window_and_spare_the_root():
    rot = Rotation.random(40 * 32 * 21, random_state=3).as_quat().reshape(40, 32, 21, 4).astype(np.float32)
    off = _offsets(rot, joint_offsets(rot, np.random.default_rng(0), 10.0, 0.5))
    assert np.abs(off - off[:, :1]).max() < 1e-4  # the same offset on every frame, keys and targets alike
    angle = _angles_deg(off[:, 0])  # (B, J)
    assert angle[:, 0].max() < 1e-3  # the root joint is the capture's
    touched = angle.max(axis=1) > 1e-3
    assert 10 <= touched.sum() <= 30  # about half of 40 windows
    assert (angle[touched, 1:] > 1e-3).all()  # every other joint of a touched window


@pytest.mark.parametrize("sigma", [5.0, 15.0])
def test_the_angle_is_half_normal_with_the_knob_as_its_rms(sigma):
    rot = np.zeros((400, 2, 21, 4), np.float32)
    rot[..., 3] = 1.0
    angle = _angles_deg(_offsets(rot, joint_offsets(rot, np.random.default_rng(1), sigma, 1.0)))[:, 0, 1:]
    assert np.sqrt(np.mean(angle**2)) == pytest.approx(sigma, rel=0.03)
    assert np.mean(angle < sigma) == pytest.approx(0.6827, abs=0.02)  # |N(0, σ)|: 68 % under σ
    assert np.mean(angle < 2 * sigma) == pytest.approx(0.9545, abs=0.01)


@pytest.fixture(scope="module")
def clips():
    rng = np.random.default_rng(7)
    n, J = 600, 21
    # Smooth random motion: a slowly turning rotation per joint, a drifting root.
    rv = np.cumsum(rng.normal(scale=0.02, size=(n, J, 3)), axis=0)
    rot = Rotation.from_rotvec(rv.reshape(-1, 3)).as_quat().reshape(n, J, 4).astype(np.float32)
    root = (np.cumsum(rng.normal(size=(n, 3)), axis=0) + [0, 93, 0]).astype(np.float32)
    return ClipSet(["a", "b"], np.array([0, 300]), np.array([300, 300]), rot, root, 30.0)


def _batch(clips, **knobs):
    cfg = TrainConfig(steps=100, batch=8, lengths=(64,), seed=5, **knobs)
    skel = bandai_skeleton()
    return step_batch(cfg, clips, skel, [skel.index(n) for n in FOOT_JOINTS], 3)


def test_knob_zero_gives_the_same_batches_and_the_knob_only_offsets_poses(clips):
    plain, zero, on = _batch(clips), _batch(clips, joint_offsets=0.0), _batch(clips, joint_offsets=10.0)
    for k in plain:
        a, b = plain[k], zero[k]
        assert a == b if isinstance(a, int) else bool((a == b).all()), k
    # The same windows, keys and root path: only the joints' rotations differ.
    for k in ("keys", "between", "croot", "max_gap", "L"):
        assert (np.asarray(plain[k]) == np.asarray(on[k])).all(), k
    changed = (plain["crot"] != on["crot"]).flatten(1).any(1)
    assert 0 < int(changed.sum()) < 8
    assert (plain["crot"][:, :, 0] == on["crot"][:, :, 0]).all()


def test_the_knob_is_range_checked():
    with pytest.raises(ValueError, match="--joint-offsets"):
        TrainConfig(joint_offsets=-1.0)
    with pytest.raises(ValueError, match="--joint-offsets"):
        TrainConfig(joint_offsets=float("nan"))
