"""sim.se3: rotations and rigid transforms against hand-computed values and identities."""

from __future__ import annotations

import numpy as np
import pytest

from sim.se3 import (
    hat,
    interpolate_pose,
    invert_pose,
    look_at,
    make_pose,
    quat_to_rot,
    rot_to_quat,
    rotation_from_euler,
    se3_exp,
    se3_log,
    so3_exp,
    so3_left_jacobian,
    so3_log,
    so3_right_jacobian,
    vee,
)

RZ90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # x -> y, y -> -x


def random_axes(n: int, seed: int = 0) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_hat_is_the_cross_product_and_vee_inverts_it():
    rng = np.random.default_rng(1)
    w, v = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    np.testing.assert_allclose((hat(w) @ v[:, :, None])[:, :, 0], np.cross(w, v), atol=1e-15)
    np.testing.assert_array_equal(vee(hat(w)), w)
    assert hat(np.zeros((2, 4, 3))).shape == (2, 4, 3, 3)


def test_so3_exp_of_a_quarter_turn_about_z():
    np.testing.assert_allclose(so3_exp([0.0, 0.0, np.pi / 2]), RZ90, atol=1e-15)
    np.testing.assert_allclose(so3_log(RZ90), [0.0, 0.0, np.pi / 2], atol=1e-15)


@pytest.mark.parametrize(
    "angle", [0.0, 1e-14, 1e-9, 1e-5, 0.01, 0.3, 1.0, 2.5, np.pi - 0.05, np.pi - 1e-4,
              np.pi - 1e-9]
)
def test_so3_exp_log_round_trip(angle):
    w = angle * random_axes(20, seed=int(angle * 1000) % 97)
    R = so3_exp(w)
    np.testing.assert_allclose(np.swapaxes(R, 1, 2) @ R, np.broadcast_to(np.eye(3), R.shape),
                               atol=1e-15)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-14)
    np.testing.assert_allclose(so3_log(R), w, rtol=0, atol=1e-12)


def test_so3_tiny_angles_follow_the_first_order_expansion():
    w = np.array([3e-10, -1e-10, 2e-10])
    # exp(w) = I + hat(w) + O(|w|^2) = I + hat(w) + O(1e-19).
    np.testing.assert_allclose(so3_exp(w), np.eye(3) + hat(w), rtol=0, atol=1e-19)
    np.testing.assert_allclose(so3_log(np.eye(3) + hat(w)), w, rtol=1e-9)


def test_so3_log_at_exactly_pi_returns_a_valid_half_turn():
    for axis in random_axes(10, seed=3):
        R = 2.0 * np.outer(axis, axis) - np.eye(3)  # half turn: R = 2 n n^T - I
        w = so3_log(R)
        assert np.linalg.norm(w) == pytest.approx(np.pi, abs=1e-12)
        assert abs(abs(w @ axis) - np.pi) < 1e-12  # along +-axis
        np.testing.assert_allclose(so3_exp(w), R, atol=1e-14)


def test_so3_is_vectorised_over_leading_axes():
    w = np.random.default_rng(4).normal(size=(2, 3, 3))
    R = so3_exp(w)
    assert R.shape == (2, 3, 3, 3)
    np.testing.assert_allclose(R[1, 2], so3_exp(w[1, 2]))
    assert so3_log(R).shape == (2, 3, 3)


@pytest.mark.parametrize("scale", [1e-7, 0.05, 1.0, 2.8])
def test_right_jacobian_matches_finite_differences(scale):
    w = scale * np.array([0.3, -0.8, 0.5])
    h = 1e-6
    numeric = np.stack(
        [so3_log(so3_exp(w).T @ so3_exp(w + h * e)) / h for e in np.eye(3)], axis=1
    )
    np.testing.assert_allclose(so3_right_jacobian(w), numeric, atol=5e-6)
    # J_l(w) = R J_r(w)
    np.testing.assert_allclose(so3_left_jacobian(w), so3_exp(w) @ so3_right_jacobian(w),
                               atol=1e-14)


def test_quaternion_of_known_rotations():
    s = np.sqrt(0.5)
    # 90 deg about z: q = (0, 0, sin 45, cos 45).
    np.testing.assert_allclose(quat_to_rot([0.0, 0.0, s, s]), RZ90, atol=1e-15)
    # 120 deg about (1, 1, 1)/sqrt(3): q = (1/2, 1/2, 1/2, 1/2), cycles x -> y -> z -> x.
    cycle = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    np.testing.assert_allclose(quat_to_rot([0.5, 0.5, 0.5, 0.5]), cycle, atol=1e-15)
    np.testing.assert_allclose(rot_to_quat(cycle), [0.5, 0.5, 0.5, 0.5], atol=1e-15)
    # Not normalised: the same rotation.
    np.testing.assert_allclose(quat_to_rot([0.0, 0.0, 3.0, 3.0]), RZ90, atol=1e-15)


def test_quaternion_round_trip_has_scalar_last_and_nonnegative_w():
    rng = np.random.default_rng(5)
    q = rng.normal(size=(200, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 3] < 0] *= -1
    back = rot_to_quat(quat_to_rot(q))
    np.testing.assert_allclose(back, q, atol=1e-14)
    # Half-turns about x, y, z exercise every branch of Shepperd's method.
    for w in (0.999 * np.pi * np.eye(3)):
        R = so3_exp(w)
        qr = rot_to_quat(R)
        assert qr[3] >= 0
        np.testing.assert_allclose(quat_to_rot(qr), R, atol=1e-14)


def test_zero_quaternion_is_rejected():
    with pytest.raises(ValueError, match="non-zero"):
        quat_to_rot([0.0, 0.0, 0.0, 0.0])


def test_se3_exp_log_round_trip_and_known_cases():
    rng = np.random.default_rng(6)
    xi = np.concatenate([rng.normal(size=(50, 3)), 0.9 * random_axes(50) * np.pi], axis=1)
    np.testing.assert_allclose(se3_log(se3_exp(xi)), xi, atol=1e-12)
    # Pure translation.
    np.testing.assert_allclose(se3_exp([1.0, 2.0, 3.0, 0.0, 0.0, 0.0]),
                               make_pose(np.eye(3), [1.0, 2.0, 3.0]), atol=1e-15)
    # A screw along its own axis: translation along z is unchanged by the rotation about z.
    np.testing.assert_allclose(se3_exp([0.0, 0.0, 0.7, 0.0, 0.0, np.pi / 2]),
                               make_pose(RZ90, [0.0, 0.0, 0.7]), atol=1e-15)


def test_invert_pose():
    T = se3_exp(np.random.default_rng(7).normal(size=(4, 6)))
    np.testing.assert_allclose(T @ invert_pose(T), np.broadcast_to(np.eye(4), T.shape),
                               atol=1e-14)


def test_interpolate_pose_endpoints_and_constant_speed():
    T0 = make_pose(so3_exp([0.1, 0.2, -0.3]), [1.0, 0.0, 2.0])
    T1 = make_pose(so3_exp([-0.4, 1.0, 0.5]), [0.0, 3.0, 1.0])
    np.testing.assert_allclose(interpolate_pose(T0, T1, 0.0), T0, atol=1e-14)
    np.testing.assert_allclose(interpolate_pose(T0, T1, 1.0), T1, atol=1e-14)
    s = np.linspace(0.0, 1.0, 11)
    T = interpolate_pose(T0, T1, s)
    assert T.shape == (11, 4, 4)
    steps = se3_log(invert_pose(T[:-1]) @ T[1:])
    # Every step is the same body twist, a tenth of the whole motion.
    np.testing.assert_allclose(steps, np.broadcast_to(steps[0], steps.shape), atol=1e-13)
    np.testing.assert_allclose(steps[0], se3_log(invert_pose(T0) @ T1) / 10, atol=1e-13)
    # Halfway through a quarter turn about z is an eighth turn.
    half = interpolate_pose(np.eye(4), make_pose(RZ90, np.zeros(3)), 0.5)
    np.testing.assert_allclose(half[:3, :3], so3_exp([0.0, 0.0, np.pi / 4]), atol=1e-15)


def test_rotation_from_euler_is_extrinsic_xyz_in_degrees():
    np.testing.assert_allclose(rotation_from_euler([0.0, 0.0, 90.0]), RZ90, atol=1e-15)
    # x by 90 maps y to z; then y by 90 maps z to x: so y ends on x.
    R = rotation_from_euler([90.0, 90.0, 0.0])
    np.testing.assert_allclose(R @ [0.0, 1.0, 0.0], [1.0, 0.0, 0.0], atol=1e-15)
    with pytest.raises(ValueError, match="3 finite numbers"):
        rotation_from_euler([1.0, 2.0])


def test_look_at_puts_the_target_on_the_axis_and_up_upwards():
    position = np.array([1.0, -2.0, 0.5])
    target = np.array([0.3, 1.0, 0.9])
    up = np.array([0.0, 0.0, 1.0])
    R = look_at(position, target, up)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-15)
    assert np.linalg.det(R) == pytest.approx(1.0)
    forward = R.T @ (target - position)
    np.testing.assert_allclose(forward / np.linalg.norm(forward), [0.0, 0.0, 1.0], atol=1e-15)
    # A point above the target appears above the image centre: negative y (v < cy).
    above = R.T @ (target + 0.1 * up - position)
    assert above[1] < 0 and abs(above[0]) < 1e-12
    # Looking along +y with z up, world +x is to the right (camera +x).
    R2 = look_at([0.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    np.testing.assert_allclose(R2, [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]],
                               atol=1e-15)


def test_look_at_rejects_degenerate_input():
    with pytest.raises(ValueError, match="equals the position"):
        look_at([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="parallel"):
        look_at([0.0, 0.0, 0.0], [0.0, 0.0, -2.0], [0.0, 0.0, 1.0])
