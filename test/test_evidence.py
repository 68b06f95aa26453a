"""The covariance a match's own evidence supports: the search's score surface (Olson 2009).

Unit figures of :mod:`laser_odom.core.uncertainty.evidence` against hand computations, then the
pipeline on simulated pairs of scans with ``prior: none``: a well-constrained match
keeps the matcher's covariance, a corridor's match grows along the axis (by the
spread of poses that score alike there) and not across it.
"""

import math

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import PipelineConfig
from laser_odom.core.events import EventLog
from laser_odom.core.pipeline.odometry import OdometryPipeline
from laser_odom.core.simulation import get_world, LaserModel, render_scan
from laser_odom.core.uncertainty.evidence import (
    excess, FLOOR_CELLS, likelihood_weights, spread_about, surface_covariance)


def test_scores_read_as_relative_likelihoods():
    weights = likelihood_weights(np.array([0.8, 0.75, 0.7, 0.4]), 40.0)
    np.testing.assert_allclose(weights, [1.0, math.exp(-2.0), math.exp(-4.0), math.exp(-16.0)])
    assert likelihood_weights(np.zeros(0), 40.0).size == 0


def test_spread_is_taken_about_the_chosen_pose_and_wraps_angles():
    poses = np.array([[1.0, 2.0, math.pi - 0.1], [2.0, 2.0, -math.pi + 0.1]])
    moment = spread_about(poses, np.array([1.0, 1.0]), np.array([1.0, 2.0, math.pi - 0.1]))
    # About the first pose: the second is 1 m along x and 0.2 rad on (across +-pi).
    np.testing.assert_allclose(moment, [[0.5, 0.0, 0.1], [0.0, 0.0, 0.0], [0.1, 0.0, 0.02]],
                               atol=1e-12)
    assert not np.any(spread_about(poses, np.zeros(2), poses[0]))


def test_only_the_part_beyond_the_floor_counts_in_metric_directions():
    # 0.3 m^2 along x, 0.004 m^2 along y, rotation 0.01 rad^2 at a 2 m length scale
    # (0.04 m^2 of arc); a floor of 0.01 m^2 leaves 0.29, 0 and 0.03 m^2 of arc.
    out = excess(np.diag([0.3, 0.004, 0.01]), 0.01, 2.0)
    np.testing.assert_allclose(out, np.diag([0.29, 0.0, 0.03 / 4.0]), atol=1e-12)


def test_a_sharp_peak_adds_nothing_and_a_flat_ridge_adds_its_length():
    cell = 0.1
    centre = np.zeros(3)
    # A unique peak: poses one cell around it, a little lower.
    offsets = np.array([[dx, dy, 0.0] for dx in (-cell, 0, cell) for dy in (-cell, 0, cell)])
    scores = 0.8 - 0.05 * np.abs(offsets[:, :2]).sum(axis=1) / cell
    assert not np.any(surface_covariance(offsets, scores, centre, 40.0, cell, 5.0))
    # A corridor: every pose 1 m either way along x scores alike.
    ridge = np.array([[x, 0.0, 0.0] for x in np.linspace(-1.0, 1.0, 21)])
    grown = surface_covariance(ridge, np.full(21, 0.8), centre, 40.0, cell, 5.0)
    along = np.mean(np.square(ridge[:, 0]))
    np.testing.assert_allclose(grown[0, 0], along - (FLOOR_CELLS * cell) ** 2, rtol=1e-9)
    assert abs(grown[1, 1]) < 1e-12 and abs(grown[2, 2]) < 1e-12


def pair(world_name: str, start_time: float, motion: np.ndarray, seed: int = 0,
         laser: LaserModel | None = None):
    world = get_world(world_name)
    start = world.path.poses_at(np.array([start_time]))[0]
    rng = np.random.default_rng(seed)
    laser = laser if laser is not None else LaserModel()
    return [render_scan(world, pose, laser, rng, 1_000_000_000 + k * 500_000_000)
            for k, pose in enumerate((start, se2.compose(start, motion)))]


def second_step(matcher: str, scans, said=None):
    config = PipelineConfig(matcher=matcher)
    config.motion.prior = 'none'
    pipeline = OdometryPipeline(config, events=EventLog(said.append if said is not None
                                                        else (lambda message: None)))
    pipeline.process(scans[0])
    return pipeline.process(scans[1]), pipeline


@pytest.mark.parametrize('matcher', ['plicp', 'nicp', 'imls'])
def test_a_well_constrained_match_keeps_the_matchers_covariance(matcher):
    estimate, pipeline = second_step(matcher, pair('office', 25.0,
                                                   se2.pose(0.6, 0.1, math.radians(20.0))))
    assert estimate.status == 'matched'
    assert not np.any(estimate.match.extra['surface_covariance'])
    np.testing.assert_array_equal(estimate.step_covariance, estimate.match.covariance)
    assert np.sqrt(np.linalg.eigvalsh(estimate.step_covariance)[-1]) < 0.01
    assert pipeline.counters['weakly_constrained'] == 0


def test_a_featureless_corridor_grows_along_its_axis_and_says_so():
    said = []
    estimate, pipeline = second_step('plicp', pair('featureless_corridor', 5.0,
                                                   se2.pose(0.8, 0.0, 0.0)), said)
    assert estimate.status == 'degenerate'
    grown = estimate.match.extra['surface_covariance']
    values, vectors = np.linalg.eigh(grown[:2, :2])
    # The corridor runs along the path's heading (x): the spread lies along it, metres
    # of it, and nothing across.
    assert abs(vectors[0, 1]) > 0.99 and np.sqrt(values[1]) > 0.5
    assert np.sqrt(estimate.step_covariance[1, 1]) < 0.01
    assert pipeline.counters['weakly_constrained'] == 1
    assert any('weakly constrained' in message for message in said)
