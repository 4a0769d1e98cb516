"""Rotations and forward kinematics against independent computations."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pipeline.motion import Motion, Skeleton
from pipeline.motion.fk import fk, fk_torch
from pipeline.motion.rotations import (
    euler_to_quat,
    quat_continuity,
    quat_to_6d,
    quat_to_euler,
    sixd_to_quat,
    slerp,
)

RNG = np.random.default_rng(0)


def chain_skeleton():
    # root -> a -> b, root -> c: offsets chosen so mistakes in order or parent show up.
    return Skeleton(
        ("root", "a", "b", "c"),
        np.array([-1, 0, 1, 0]),
        np.array([[0, 90, 0], [0, 10, 0], [5, 0, 0], [0, -20, 3]], np.float32),
    )


def matrix_fk(rot, root, parents, offsets):
    """Independent FK with 4x4 homogeneous matrices (column vectors)."""
    J = len(parents)
    world = [None] * J
    for j in range(J):
        m = np.eye(4)
        m[:3, :3] = Rotation.from_quat(rot[j]).as_matrix()
        m[:3, 3] = root if parents[j] < 0 else offsets[j]
        world[j] = m if parents[j] < 0 else world[parents[j]] @ m
    return np.array([w[:3, 3] for w in world])


def test_fk_matches_matrix_chain():
    skel = chain_skeleton()
    rot = Rotation.random(5 * 4, random_state=1).as_quat().reshape(5, 4, 4).astype(np.float32)
    root = RNG.normal(size=(5, 3)).astype(np.float32)
    _, pos = fk(rot, root, skel.parents, skel.offsets)
    for t in range(5):
        np.testing.assert_allclose(pos[t], matrix_fk(rot[t], root[t], skel.parents, skel.offsets), atol=1e-4)


def test_fk_hand_computed():
    skel = chain_skeleton()
    # Root turned 90° about Z: local +Y becomes world -X.
    rot = np.tile([0, 0, 0, 1.0], (1, 4, 1)).astype(np.float32)
    rot[0, 0] = Rotation.from_euler("Z", 90, degrees=True).as_quat()
    _, pos = fk(rot, np.zeros((1, 3), np.float32), skel.parents, skel.offsets)
    np.testing.assert_allclose(pos[0, 1], [-10, 0, 0], atol=1e-5)
    np.testing.assert_allclose(pos[0, 2], [-10, 5, 0], atol=1e-5)
    np.testing.assert_allclose(pos[0, 3], [20, 0, 3], atol=1e-5)


def test_torch_fk_matches_numpy():
    torch = pytest.importorskip("torch")
    skel = chain_skeleton()
    rot = Rotation.random(12, random_state=2).as_quat().reshape(3, 4, 4)
    root = RNG.normal(size=(3, 3))
    gq, gp = fk(rot, root, skel.parents, skel.offsets)
    tq, tp = fk_torch(torch.tensor(rot), torch.tensor(root), skel.parents, skel.offsets)
    np.testing.assert_allclose(tp.numpy(), gp, atol=1e-6)
    # Same rotation up to sign.
    dots = np.abs((tq.numpy() * gq).sum(-1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-6)


@pytest.mark.parametrize("order", ["XYZ", "ZXY", "ZYX", "YXZ", "XZY", "YZX"])
def test_euler_round_trip_any_order(order):
    ang = RNG.uniform(-80, 80, size=(50, 3))
    q = euler_to_quat(ang, order)
    np.testing.assert_allclose(quat_to_euler(q, order), ang, atol=1e-6)


def test_euler_intrinsic_channel_order():
    # ZXY intrinsic: R = Rz · Rx · Ry.
    z, x, y = 30.0, -20.0, 75.0
    expect = (
        Rotation.from_euler("z", z, degrees=True)
        * Rotation.from_euler("x", x, degrees=True)
        * Rotation.from_euler("y", y, degrees=True)
    )
    q = euler_to_quat(np.array([z, x, y]), "ZXY")
    assert abs(abs(np.dot(q, expect.as_quat())) - 1) < 1e-9


def test_sixd_round_trip():
    q = Rotation.random(100, random_state=3).as_quat()
    back = sixd_to_quat(quat_to_6d(q))
    np.testing.assert_allclose(np.abs((back * q).sum(-1)), 1.0, atol=1e-9)


def test_slerp_endpoints_midpoint_and_short_arc():
    a = Rotation.from_euler("y", 0, degrees=True).as_quat()
    b = Rotation.from_euler("y", 90, degrees=True).as_quat()
    out = slerp(a, -b, np.array([0.0, 0.5, 1.0]))  # -b: must still take the short arc
    np.testing.assert_allclose(np.abs(out[0] @ a), 1, atol=1e-12)
    np.testing.assert_allclose(np.abs(out[2] @ b), 1, atol=1e-12)
    mid = Rotation.from_quat(out[1]).as_euler("xyz", degrees=True)
    np.testing.assert_allclose(mid, [0, 45, 0], atol=1e-9)


def test_quat_continuity_removes_flips():
    q = Rotation.from_euler("y", np.linspace(0, 300, 40)[:, None], degrees=True).as_quat()
    q[::3] *= -1
    c = quat_continuity(q)
    assert ((c[1:] * c[:-1]).sum(-1) > 0).all()


def test_motion_rejects_bad_shapes():
    skel = chain_skeleton()
    with pytest.raises(ValueError, match="rotations"):
        Motion(skel, np.zeros((4, 3, 4)), np.zeros((4, 3)), 30)
    with pytest.raises(ValueError, match="root positions"):
        Motion(skel, np.zeros((4, 4, 4)), np.zeros((5, 3)), 30)
