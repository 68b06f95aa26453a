"""Prior buffers: wheel-odometry motion and IMU yaw change between two scan stamps."""

import math

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.core.configuration.node import prior_config_from_params, PriorConfig
from laser_odom.core.motion.priors import external_prior, ImuBuffer, OdometryBuffer
from laser_odom.core.parameters import ParameterError

SECOND = 1_000_000_000


def arc(t: np.ndarray, v: float = 0.8, w: float = 0.6) -> np.ndarray:
    """Poses on a circle driven at speed ``v`` and turn rate ``w`` (exact, closed form)."""
    theta = w * t
    return np.column_stack((v / w * np.sin(theta), v / w * (1.0 - np.cos(theta)),
                            se2.wrap_angle(theta + 2.5)))


def test_odometry_motion_between_interpolates_at_scan_stamps():
    buffer = OdometryBuffer()
    t = np.arange(0.0, 3.0, 0.02)
    poses = arc(t)
    for stamp, pose in zip(t, poses):
        buffer.add(int(round(stamp * SECOND)) + 7 * SECOND, pose)
    start, end = 7 * SECOND + 1_230_000_000, 7 * SECOND + 1_337_000_000
    motion = buffer.motion_between(start, end)
    truth = se2.relative(arc(np.array([1.23]))[0], arc(np.array([1.337]))[0])
    assert np.allclose(motion, truth, atol=2e-4)


def test_odometry_extrapolates_briefly_then_goes_stale():
    buffer = OdometryBuffer(PriorConfig(prior_max_extrapolation=0.05))
    t = np.arange(0.0, 1.0 + 1e-9, 0.02)
    for stamp, pose in zip(t, arc(t)):
        buffer.add(int(round(stamp * SECOND)), pose)
    motion = buffer.motion_between(int(0.9 * SECOND), int(1.03 * SECOND))
    truth = se2.relative(arc(np.array([0.9]))[0], arc(np.array([1.03]))[0])
    assert np.allclose(motion, truth, atol=1e-3)
    assert buffer.motion_between(int(0.9 * SECOND), int(1.06 * SECOND)) is None
    assert buffer.motion_between(-1, int(0.5 * SECOND)) is None


def test_odometry_buffer_is_bounded_and_restarts_after_time_jump():
    buffer = OdometryBuffer(PriorConfig(prior_buffer_duration=1.0))
    for i in range(500):
        buffer.add(i * 10_000_000, se2.pose(i * 0.01, 0.0, 0.0))
    assert len(buffer) <= 102
    assert buffer.motion_between(2 * SECOND, 3 * SECOND) is None
    assert buffer.motion_between(4 * SECOND, int(4.5 * SECOND))[0] == pytest.approx(0.5)
    buffer.add(SECOND, se2.pose())
    assert len(buffer) == 1 and buffer.time_jumps == 1


def test_imu_yaw_change_from_orientation_crosses_pi():
    buffer = ImuBuffer()
    t = np.arange(0.0, 2.0, 0.01)
    yaw = se2.wrap_angle(3.0 + 0.9 * t)
    for stamp, y in zip(t, yaw):
        buffer.add(int(round(stamp * SECOND)), float(y), 0.9)
    change = buffer.yaw_change(int(0.105 * SECOND), int(0.5 * SECOND))
    assert change == pytest.approx(0.9 * 0.395, abs=1e-9)


def test_imu_yaw_change_integrates_rate_without_orientation():
    buffer = ImuBuffer()
    t = np.arange(0.0, 2.0, 0.01)
    for stamp in t:
        buffer.add(int(round(stamp * SECOND)), None, 0.5 + 0.4 * stamp)
    start, end = 0.333, 1.777
    expected = 0.5 * (end - start) + 0.2 * (end ** 2 - start ** 2)
    change = buffer.yaw_change(int(start * SECOND), int(end * SECOND))
    assert change == pytest.approx(expected, abs=1e-9)


def test_external_prior_picks_the_configured_source():
    odometry, imu = OdometryBuffer(), ImuBuffer()
    for i in range(11):
        odometry.add(i * 100_000_000, se2.pose(0.1 * i, 0.0, 0.0))
        imu.add(i * 100_000_000, 0.05 * i, 0.5)
    step, yaw = external_prior('odom', 200_000_000, 500_000_000, odometry, imu)
    assert np.allclose(step, [0.3, 0.0, 0.0]) and yaw is None
    step, yaw = external_prior('imu', 200_000_000, 500_000_000, odometry, imu)
    assert step is None and yaw == pytest.approx(0.15)
    assert external_prior('odom', None, 500_000_000, odometry) == (None, None)
    assert external_prior('constant_velocity', 0, 500_000_000, odometry) == (None, None)
    assert math.isfinite(external_prior('imu', 0, 10 ** 9, None, imu)[1])


def test_prior_config_from_params_validates():
    config = prior_config_from_params({'prior_max_extrapolation': 0.2, 'matcher': 'icp'})
    assert config.prior_max_extrapolation == 0.2
    with pytest.raises(ParameterError, match='below the minimum'):
        prior_config_from_params({'prior_buffer_duration': 0.0})
