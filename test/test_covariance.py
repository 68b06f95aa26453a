"""Covariance is honest: the normalised estimation error squared of each step is about 3."""

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import PipelineConfig
from laser_odom.core.events import EventLog
from laser_odom.core.matchers import matcher_names
from laser_odom.core.matchers.information import (
    MIN_RESIDUAL_SIGMA, point_to_line_information, point_to_line_jacobians)
from laser_odom.core.pipeline.odometry import OdometryPipeline
from laser_odom.core.simulation import LaserModel, simulate

DOF = 3


@pytest.fixture(scope='module')
def long_run():
    """1000 scans (100 s) in the office world with 1 cm Gaussian range noise."""
    return simulate('office', duration=100.0, laser=LaserModel(noise_sigma=0.01), seed=5)


def step_nees(run, matcher: str) -> np.ndarray:
    """Return e^T S^-1 e of every matched step (e: error of the per-step motion)."""
    pipeline = OdometryPipeline(PipelineConfig(matcher=matcher),
                                events=EventLog(lambda message: None))
    truth = run.reference.poses
    values = []
    for index, scan in enumerate(run.scans):
        estimate = pipeline.process(scan)
        if estimate is None or estimate.status != 'matched':
            continue
        dt = (scan.stamp_ns - run.scans[index - 1].stamp_ns) * 1e-9
        error = estimate.twist * dt - se2.relative(truth[index - 1], truth[index])
        error[2] = se2.wrap_angle(error[2])
        covariance = estimate.twist_covariance * dt * dt
        values.append(float(error @ np.linalg.solve(covariance, error)))
    return np.array(values)


@pytest.mark.parametrize('matcher', matcher_names())
def test_mean_nees_of_the_step_is_consistent(long_run, matcher):
    nees = step_nees(long_run, matcher)
    assert len(nees) >= 900  # nearly every step was matched and scored
    assert 0.5 * DOF <= nees.mean() <= 2.0 * DOF, nees.mean()


def test_point_to_line_information_is_the_weighted_gauss_newton_information():
    rng = np.random.default_rng(4)
    points = rng.normal(size=(50, 2)) * 3.0
    angles = rng.uniform(-np.pi, np.pi, 50)
    normals = np.column_stack((np.cos(angles), np.sin(angles)))
    residuals = rng.normal(size=50) * 0.02
    weights = rng.uniform(0.2, 1.0, 50)
    jacobians = point_to_line_jacobians(points, normals)
    summed = np.einsum('n,ni,nj->ij', weights, jacobians, jacobians)
    variance = np.sum(weights * residuals ** 2) / (np.sum(weights) - 3.0)
    np.testing.assert_allclose(point_to_line_information(points, normals, residuals, weights),
                               summed / variance, rtol=1e-12)
    tiny = residuals * 1e-3  # below the floor: the variance is MIN_RESIDUAL_SIGMA^2
    np.testing.assert_allclose(point_to_line_information(points, normals, tiny, weights),
                               summed / MIN_RESIDUAL_SIGMA ** 2, rtol=1e-12)
