"""Choosing among the search's refined candidates (:func:`.recovery.choose`).

Among poses that fit alike, the one nearest a trusted prediction is taken - unless even
the best of them fits poorly and the prediction's own match failed its checks: then the
scans share too little to tell the poses apart by a refuted prediction. fr079 every
10th scan 0.1 s apart (imls, scan 132: an 88 deg turn, the pose found by the search
fitting 0.391 against 0.384 at the prediction's) took the pose nearest the wrong
prediction, where ``prior: none`` took the right one. A prediction only doubted (a
step too large for the matcher alone) stays the tie-break: a fast spin seen by a sparse
lidar fits poorly everywhere, and there the prediction is right.
"""

import math

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import PipelineConfig
from laser_odom.core.matchers import MatchResult
from laser_odom.core.motion.blind_prior import Prediction
from laser_odom.core.registration import recovery
from laser_odom.core.scan.laser_scan import ScanPoints
from laser_odom.core.search import SearchWindow

NEAR = se2.pose(0.05, -0.28, -0.08)
"""A candidate close to the trusted prediction below."""

FAR = se2.pose(0.49, 0.53, 1.42)
"""A candidate a large turn away from it."""

PREDICTED = se2.pose(-0.11, -0.04, 0.35)


def ring(count: int = 120, radius: float = 4.0) -> ScanPoints:
    """Return points on a circle: the fits are set by the test, not measured on them."""
    angles = np.linspace(-math.pi, math.pi, count, endpoint=False)
    points = radius * np.column_stack((np.cos(angles), np.sin(angles)))
    return ScanPoints(points, np.arange(count), np.full(count, radius))


def candidate(pose: np.ndarray) -> MatchResult:
    """Return a converged, well-paired refinement at ``pose``."""
    return MatchResult(pose=np.array(pose, dtype=float), converged=True, iterations=5,
                       inlier_ratio=0.8, residual=0.02, information=np.eye(3) * 1e4,
                       covariance=np.eye(3) * 1e-4)


@pytest.fixture
def fits(monkeypatch):
    """Return a dict pose-key -> surface fit that :func:`recovery.surface_fit` answers."""
    table: dict[tuple, float] = {}

    def surface_fit(reference, points, pose, sigma):
        return table[tuple(np.round(pose, 6))], 0.9

    monkeypatch.setattr(recovery, 'surface_fit', surface_fit)
    return table


def chosen(fits, near_fit: float, far_fit: float, trusted: bool = True,
           refuted: bool = True) -> np.ndarray:
    """Return the pose :func:`recovery.choose` takes, the fits of both candidates given.

    ``refuted``: the match from the trusted prediction failed its checks.
    """
    fits[tuple(np.round(NEAR, 6))] = near_fit
    fits[tuple(np.round(FAR, 6))] = far_fit
    config = PipelineConfig()
    window = SearchWindow(3.0, math.pi, config.search.global_search_resolution)
    prediction = Prediction(PREDICTED, np.diag([0.04, 0.04, 0.1]), 'prior')
    scan = ring()
    choice = recovery.choose(scan, scan, PREDICTED, config, window, None,
                             [candidate(NEAR), candidate(FAR)], None, trusted, prediction,
                             refuted)
    return choice.match.pose


def test_among_poses_that_fit_well_alike_the_nearest_the_prediction_is_taken(fits):
    assert PipelineConfig().search.global_search_poor_fit < 0.8
    np.testing.assert_allclose(chosen(fits, 0.80, 0.84), NEAR)


def test_among_poses_that_fit_poorly_a_refuted_prediction_gives_way_to_the_best_fit(fits):
    poor = PipelineConfig().search.global_search_poor_fit
    assert 0.391 < poor and 0.384 >= 0.9 * 0.391  # alike, and poor
    np.testing.assert_allclose(chosen(fits, 0.384, 0.391), FAR)
    np.testing.assert_allclose(chosen(fits, 0.391, 0.384), NEAR)


def test_among_poses_that_fit_poorly_a_doubted_prediction_stays_the_tie_break(fits):
    np.testing.assert_allclose(chosen(fits, 0.384, 0.391, refuted=False), NEAR)


def test_a_clearly_better_fit_wins_whatever_the_prediction(fits):
    np.testing.assert_allclose(chosen(fits, 0.60, 0.90), FAR)
    np.testing.assert_allclose(chosen(fits, 0.60, 0.90, trusted=False), FAR)
