"""Degenerate scenes: a featureless corridor is flagged and its covariance says so."""

import numpy as np
import pytest

from laser_odom.core.configuration.pipeline import PipelineConfig
from laser_odom.core.evaluation.metrics import evaluate
from laser_odom.core.events import EventLog
from laser_odom.core.matchers import matcher_names
from laser_odom.core.pipeline.odometry import OdometryPipeline
from laser_odom.core.pipeline.runner import run_pipeline
from laser_odom.core.simulation import simulate


@pytest.fixture(scope='module')
def corridor_run():
    """Twelve seconds straight down a corridor with smooth walls (along world x)."""
    return simulate('featureless_corridor', duration=12.0, seed=1)


@pytest.mark.parametrize('matcher', matcher_names())
def test_featureless_corridor_is_flagged_with_honest_covariance(corridor_run, matcher):
    pipeline = OdometryPipeline(PipelineConfig(matcher=matcher),
                                events=EventLog(lambda message: None))
    result = run_pipeline(pipeline, corridor_run.scans)
    matches = len(corridor_run.scans) - 1
    assert pipeline.counters['degenerate'] >= 0.8 * matches
    # Published covariance: at least 10x larger along the corridor (x) than across (y).
    covariance = result.pose_covariances[-1]
    assert covariance[0, 0] >= 10.0 * covariance[1, 1]
    # Across the corridor and in heading the estimate stays as good as in a normal scene.
    truth = corridor_run.reference
    across = np.abs(result.trajectory.poses[:, 1] - truth.poses[:, 1])
    heading = np.abs(result.trajectory.poses[:, 2] - truth.poses[:, 2])
    assert across.max() < 0.05
    assert np.degrees(heading.max()) < 1.0
    errors = evaluate(result.trajectory, truth)
    assert errors.failed_steps == 0


@pytest.mark.parametrize('matcher', ['plicp', 'nicp', 'imls'])
def test_ignorance_along_a_corridor_accumulates(corridor_run, matcher):
    """Degenerate steps compound white, their variance along the axis kept.

    It is ignorance, not scan noise that the next match would cancel (the shared part
    of the correlated error model).
    """
    pipeline = OdometryPipeline(PipelineConfig(matcher=matcher),
                                events=EventLog(lambda message: None))
    along = []
    for scan in corridor_run.scans:
        estimate = pipeline.process(scan)
        if estimate is not None and estimate.status == 'degenerate':
            along.append(estimate.twist_covariance[0, 0])
    dt = (corridor_run.scans[1].stamp_ns - corridor_run.scans[0].stamp_ns) * 1e-9
    assert len(along) >= 0.8 * (len(corridor_run.scans) - 1)
    final = pipeline.pose_covariance[0, 0]
    assert final >= 0.9 * sum(along) * dt * dt, (final, sum(along) * dt * dt)


def test_what_the_scan_measured_has_no_information_along_a_weak_direction():
    """A corridor's axis: the matcher's small variance there is not a measurement.

    Along the weak eigenvector (x, below ``degeneracy_min_information``) the variance
    becomes :data:`.UNMEASURED_VARIANCE`; across it the match's covariance stands, and
    a match without weak directions keeps its covariance.
    """
    from laser_odom.core.configuration.pipeline import AcceptanceConfig
    from laser_odom.core.uncertainty.degeneracy import measured_only, UNMEASURED_VARIANCE
    threshold = AcceptanceConfig().degeneracy_min_information
    covariance = np.diag([1e-4, 1e-6, 1e-6])
    corridor = np.diag([0.1 * threshold, 1e6, 1e6])
    blind = measured_only(covariance, corridor, 5.0, threshold)
    assert blind[0, 0] >= UNMEASURED_VARIANCE
    np.testing.assert_allclose(blind[1:, 1:], covariance[1:, 1:], atol=1e-12)
    room = np.diag([1e6, 1e6, 1e6])
    np.testing.assert_allclose(measured_only(covariance, room, 5.0, threshold), covariance)
