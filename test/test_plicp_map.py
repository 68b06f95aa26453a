"""PL-ICP against a view of the local map: the pairs that alone see a corridor's axis pull.

Along a corridor only a few pairs (a door frame, the far end) observe the motion along
its axis. When the prediction is off along it, exactly those pairs have the largest
residuals, so trimming them from the first fine iteration on keeps the match wherever it
started: the odometry stalls (intel, issue 28). Against the map's view the fine phase
therefore starts with every pair, Huber weighted, and trims only from where that fit
settles (``plicp.map_huber_sigma``).
"""

import math

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.core.matchers import create_matcher
from laser_odom.core.matchers.plicp import PlicpConfig
from laser_odom.core.matchers.plicp.segments import (
    huber_weights, pair_and_trim, reference_segments)
from laser_odom.core.matchers.plicp.solver import iterate
from laser_odom.core.scan.laser_scan import ScanPoints

CORRIDOR = np.array([
    [-30.0, 1.0, 3.0, 1.0], [3.0, 1.0, 3.0, 1.3], [3.0, 1.3, 4.0, 1.3], [4.0, 1.3, 4.0, 1.0],
    [4.0, 1.0, 30.0, 1.0], [-30.0, -1.0, 5.0, -1.0], [5.0, -1.0, 5.0, -1.3],
    [5.0, -1.3, 6.0, -1.3], [6.0, -1.3, 6.0, -1.0], [6.0, -1.0, 30.0, -1.0]])
"""Walls (x0, y0, x1, y1) of a 2 m wide corridor along x with two door recesses, at x 3-4 m
on the left and 5-6 m on the right: their far jambs (a few beams each) are the only
surfaces across the axis that the robot near the origin sees."""

STEP = 0.06
"""The robot's true motion along the corridor [m]; the prediction says it stood still."""


def corridor_scan(x: float, bearings_deg: np.ndarray, noise: float, seed: int,
                  virtual: bool = False) -> ScanPoints:
    """Ray-cast the corridor from ``(x, 0)`` heading along it, out to 20 m."""
    bearings = np.radians(bearings_deg)
    c, s = np.cos(bearings), np.sin(bearings)
    ranges = np.full(len(bearings), np.inf)
    for ax, ay, bx, by in CORRIDOR:
        ex, ey = bx - ax, by - ay
        den = c * ey - s * ex
        safe = np.where(np.abs(den) > 1e-12, den, 1.0)
        t = ((ax - x) * ey - ay * ex) / safe
        u = ((ax - x) * s - ay * c) / safe
        hit = (np.abs(den) > 1e-12) & (t > 0.0) & (u >= 0.0) & (u <= 1.0)
        ranges = np.where(hit, np.minimum(ranges, t), ranges)
    keep = np.flatnonzero(ranges < 20.0)
    ranges = ranges[keep] + np.random.default_rng(seed).normal(0.0, noise, len(keep))
    return ScanPoints(np.c_[ranges * c[keep], ranges * s[keep]], keep, ranges,
                      virtual=virtual)


def corridor_pair(seed: int, virtual: bool = True) -> tuple[ScanPoints, ScanPoints]:
    """Return a 360 deg view of the corridor from the origin and a 180 deg scan at STEP."""
    view = corridor_scan(0.0, np.arange(-180.0, 180.0) + 0.5, 0.003, seed, virtual)
    current = corridor_scan(STEP, np.arange(-90.0, 90.0), 0.01, seed + 100)
    return view, current


@pytest.mark.parametrize('seed', range(6))
def test_a_door_frame_moves_the_match_along_the_corridor(seed):
    view, current = corridor_pair(seed)
    match = create_matcher('plicp').match(view, current, se2.pose())
    assert match.converged and abs(match.pose[0] - STEP) < 0.015, match.pose
    assert abs(match.pose[1]) < 0.005 and abs(match.pose[2]) < math.radians(0.3)
    # Trimming from the start drops the jamb's few pairs: the match stays where it began.
    trimming = create_matcher('plicp', {'map_huber_sigma': 0.0})
    trimmed = trimming.match(view, current, se2.pose())
    assert abs(trimmed.pose[0]) < 0.01, trimmed.pose


def test_against_a_scan_the_fine_phase_trims_from_the_start():
    """A previous scan holds people and edges seen from elsewhere: trimming stays."""
    view, current = corridor_pair(0, virtual=False)
    against_scan = create_matcher('plicp').match(view, current, se2.pose())
    trimming = create_matcher('plicp', {'map_huber_sigma': 0.0})
    assert np.array_equal(against_scan.pose, trimming.match(view, current, se2.pose()).pose)


def test_huber_weights_are_one_within_the_robust_sigmas_and_fall_beyond():
    residuals = np.array([0.01, -0.01, 0.02, -0.02, 0.0, 0.2, -0.5])
    sigma = 1.4826 * np.median(np.abs(residuals))
    weights = huber_weights(residuals, 3.0)
    inside = np.abs(residuals) <= 3.0 * sigma
    assert np.all(weights[inside] == 1.0)
    assert np.allclose(weights[~inside], 3.0 * sigma / np.abs(residuals[~inside]))
    assert huber_weights(np.zeros(0), 3.0).shape == (0,)


def test_a_weighted_pairing_keeps_every_pair_and_weighs_its_normal_equations():
    view, current = corridor_pair(1)
    segments = reference_segments(view, 3, 0.5)
    index = view.bearing_index
    kept, moved, line, _, weight, big_m, small_m, _, paired = pair_and_trim(
        segments.table, index.sorted_points, index.bearings, index.directions, index.order,
        current.points, se2.pose(), 0.15, -1.0, 0.9, 0.95, 3.0, 3.5,
        np.full(len(current), -1, np.int64))
    assert len(kept) == paired and np.any(weight < 1.0) and np.all(weight > 0.0)
    residuals = np.einsum('nd,nd->n', line[:, :2], moved) - line[:, 2]
    assert np.allclose(weight, huber_weights(residuals, 3.5))
    a = np.c_[line[:, :2], np.einsum('nd,nd->n', line[:, :2], moved),
              line[:, 1] * moved[:, 0] - line[:, 0] * moved[:, 1]]
    assert np.allclose(big_m, (a * weight[:, None]).T @ a, rtol=1e-12, atol=1e-12)
    assert np.allclose(small_m, (a * weight[:, None]).T @ line[:, 2], rtol=1e-12, atol=1e-12)


def test_the_weighted_start_ends_in_a_trimmed_fit():
    """Converged, the last pairs are trimmed as usual (weight one).

    The residual and the information keep their meaning, and their calibration.
    """
    view, current = corridor_pair(2)
    cfg = PlicpConfig()
    segments = reference_segments(view, cfg.max_beam_gap, cfg.max_segment_length,
                                  cfg.information_window)
    index = view.bearing_index
    found, estimate, converged, _, kept, *_, weight, _ = iterate(
        segments.table, index.sorted_points, index.bearings, index.directions, index.order,
        current.points, se2.pose(), cfg.max_iterations, cfg.min_correspondences,
        cfg.coarse_keep_fraction, cfg.coarse_correspondence_distance, cfg.coarse_step,
        cfg.max_correspondence_distance, cfg.min_keep_fraction, cfg.max_keep_fraction,
        cfg.trim_sigma, cfg.map_huber_sigma, cfg.convergence_translation,
        cfg.convergence_rotation)
    assert found and converged and abs(estimate[0] - STEP) < 0.015
    assert np.array_equal(weight, np.ones(len(kept)))
    paired = len(current)  # every beam sees a wall within the gate
    assert len(kept) <= math.ceil(cfg.max_keep_fraction * paired)
