"""SE(2) algebra: composition, inverse, matrices, quaternions, covariance Jacobians."""

import math

import numpy as np
import pytest

from laser_odom.core import se2

RNG = np.random.default_rng(7)


def random_pose() -> np.ndarray:
    return np.array([RNG.uniform(-5, 5), RNG.uniform(-5, 5), RNG.uniform(-math.pi, math.pi)])


@pytest.mark.parametrize('trial', range(20))
def test_compose_matches_matrix_product(trial):
    a, b = random_pose(), random_pose()
    expected = se2.from_matrix(se2.to_matrix(a) @ se2.to_matrix(b))
    got = se2.compose(a, b)
    assert np.allclose(got[:2], expected[:2])
    assert abs(se2.wrap_angle(got[2] - expected[2])) < 1e-12


def test_inverse_and_relative():
    a, b = random_pose(), random_pose()
    assert np.allclose(se2.compose(a, se2.inverse(a)), 0.0, atol=1e-12)
    assert np.allclose(se2.compose(a, se2.relative(a, b)), b)


def test_transform_points_matches_matrix():
    p = random_pose()
    pts = RNG.normal(size=(50, 2))
    hom = np.column_stack((pts, np.ones(50))) @ se2.to_matrix(p).T
    assert np.allclose(se2.transform_points(p, pts), hom[:, :2])


@pytest.mark.parametrize('angle', [0.0, 3.0, -3.1, 7.5, -20.0, math.pi])
def test_wrap_angle_range(angle):
    wrapped = se2.wrap_angle(angle)
    assert -math.pi <= wrapped < math.pi
    assert math.isclose(math.cos(wrapped), math.cos(angle), abs_tol=1e-12)
    assert math.isclose(math.sin(wrapped), math.sin(angle), abs_tol=1e-12)


def test_wrap_angle_array():
    wrapped = se2.wrap_angle(np.array([4.0, -4.0]))
    assert np.allclose(wrapped, [4.0 - 2 * math.pi, -4.0 + 2 * math.pi])


@pytest.mark.parametrize('yaw', [0.0, 0.5, -2.0, 3.1])
def test_quaternion_round_trip(yaw):
    q = se2.yaw_to_quaternion(yaw)
    assert math.isclose(sum(c * c for c in q), 1.0)
    assert math.isclose(se2.quaternion_to_yaw(*q), yaw, abs_tol=1e-12)


def test_compose_jacobians_match_finite_differences():
    a, b = random_pose(), random_pose()
    ja, jb = se2.compose_jacobians(a, b)
    eps = 1e-7
    for k in range(3):
        d = np.zeros(3)
        d[k] = eps
        da = (se2.compose(a + d, b) - se2.compose(a - d, b)) / (2 * eps)
        db = (se2.compose(a, b + d) - se2.compose(a, b - d)) / (2 * eps)
        assert np.allclose(da, ja[:, k], atol=1e-6)
        assert np.allclose(db, jb[:, k], atol=1e-6)


def test_inverse_jacobian_matches_finite_differences():
    pose = np.array([0.3, -0.7, 2.9])
    eps = 1e-6
    numeric = np.column_stack([
        se2.wrap_angle(se2.inverse(pose + eps * unit) - se2.inverse(pose - eps * unit))
        / (2 * eps) for unit in np.eye(3)])
    np.testing.assert_allclose(se2.inverse_jacobian(pose), numeric, atol=1e-8)


def test_pose_defaults_to_the_origin_and_rotation_is_counter_clockwise():
    assert np.array_equal(se2.pose(), np.zeros(3))
    theta = 0.3
    rot = se2.rotation(theta)
    assert np.allclose(rot @ [1.0, 0.0], [math.cos(theta), math.sin(theta)])
    assert np.allclose(rot @ [0.0, 1.0], [-math.sin(theta), math.cos(theta)])


@pytest.mark.parametrize('roll, pitch, yaw', [(0.1, -0.2, 0.7), (-0.3, 0.25, -2.5)])
def test_yaw_of_a_tilted_quaternion(roll, pitch, yaw):
    """A quaternion with roll and pitch (a tilted IMU, a 3D odometry): the ZYX yaw."""
    def axis(angle, index):
        q = np.zeros(4)  # (x, y, z, w)
        q[index], q[3] = math.sin(angle / 2.0), math.cos(angle / 2.0)
        return q

    def product(a, b):
        (ax, ay, az, aw), (bx, by, bz, bw) = a, b
        return np.array([aw * bx + ax * bw + ay * bz - az * by,
                         aw * by - ax * bz + ay * bw + az * bx,
                         aw * bz + ax * by - ay * bx + az * bw,
                         aw * bw - ax * bx - ay * by - az * bz])

    q = product(product(axis(yaw, 2), axis(pitch, 1)), axis(roll, 0))
    assert math.isclose(se2.quaternion_to_yaw(*q), yaw, abs_tol=1e-12)


def test_matrix_of_a_pose_times_that_of_its_inverse_is_the_identity():
    pose = random_pose()
    assert np.allclose(se2.to_matrix(pose) @ se2.to_matrix(se2.inverse(pose)), np.eye(3))


def test_a_small_step_is_below_both_thresholds_strictly():
    assert se2.is_small_step(np.array([3e-5, 4e-5, -9e-5]), 1e-4, 1e-4)
    assert not se2.is_small_step(np.array([6e-5, 8e-5, 0.0]), 1e-4, 1e-4)  # |t| = 1e-4
    assert not se2.is_small_step(np.array([0.0, 0.0, -1e-4]), 1e-4, 1e-4)
    assert not se2.is_small_step(np.array([0.0, 0.0, 0.0]), 0.0, 1e-4)
