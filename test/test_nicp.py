"""NICP: normals and curvature, information, pair rules, Jacobians, recovery, corridors."""

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import pipeline_config_from_params, PipelineConfig
from laser_odom.core.datasets import load_dataset
from laser_odom.core.evaluation.metrics import evaluate
from laser_odom.core.events import EventLog
from laser_odom.core.matchers import create_matcher, default_config, matcher_names
from laser_odom.core.matchers.nicp.matcher import NicpConfig, NicpMatcher
from laser_odom.core.matchers.nicp.model import (
    associate, chi_squared, dense_information, linearise, normal_equations, pair_rules,
    residuals_and_jacobians, rule_table)
from laser_odom.core.matchers.nicp.solver import damped_step, undoes
from laser_odom.core.matchers.nicp.surface import (
    nicp_surface, normal_variance, point_information, rotation_seed)
from laser_odom.core.matchers.robust import kernel_code, kernel_weights
from laser_odom.core.parameters import as_dict, ParameterError
from laser_odom.core.pipeline.odometry import OdometryPipeline
from laser_odom.core.pipeline.runner import run_pipeline
from laser_odom.core.scan.laser_scan import scan_to_points, ScanPoints
from laser_odom.core.scan.normals import estimate_normals, normals_from_neighbours
from laser_odom.core.simulation import geometry as geo, get_world, LaserModel, render_scan, World

CONFIG_FILE = Path(__file__).resolve().parents[1] / 'config' / 'nicp.yaml'

# An irregular room (no symmetry that would make a pose ambiguous) with a box and a
# pillar, so every degree of freedom is constrained.
ROOM = World(
    'nicp-room', 'irregular polygon room for the NICP tests',
    geo.stack(geo.polygon([[-4.0, -3.0], [5.0, -3.5], [6.0, 1.0], [3.5, 4.0], [-2.0, 3.5],
                           [-4.5, 1.0]]),
              geo.box(2.0, 1.5, 0.8, 0.5, 0.4), geo.pillar(-2.0, -1.0, 0.3)),
    np.zeros((2, 2)))

# Two long parallel walls and nothing else within range: x is unobservable.
CORRIDOR = World('nicp-corridor', 'two parallel walls',
                 geo.stack(geo.wall((-60.0, -1.0), (60.0, -1.0)),
                           geo.wall((-60.0, 1.0), (60.0, 1.0))), np.zeros((2, 2)))

EXACT = LaserModel(beams=360, fov=2.0 * math.pi, max_range=20.0, noise_sigma=0.0)
START = se2.pose(0.3, -0.2, 0.3)


def _points(points: np.ndarray) -> ScanPoints:
    points = np.asarray(points, dtype=float)
    return ScanPoints(points, np.arange(len(points)), np.hypot(points[:, 0], points[:, 1]))


def _scan(world: World, pose: se2.Pose, laser: LaserModel = EXACT,
          seed: int = 0) -> ScanPoints:
    return scan_to_points(render_scan(world, pose, laser, np.random.default_rng(seed)))


def _moved_copy(reference: ScanPoints, motion: se2.Pose) -> ScanPoints:
    """Return the reference's own surface points seen from a pose moved by ``motion``."""
    points = se2.transform_points(se2.inverse(motion), reference.points)
    return ScanPoints(points, reference.beam_index.copy(), np.hypot(*points.T))


# --- normals and curvature on analytic shapes ----------------------------------------

def test_normals_of_a_line_are_perpendicular_and_flat():
    xs = np.arange(-2.0, 2.0 + 1e-9, 0.02)
    scan = _points(np.column_stack((xs, np.full_like(xs, 2.0))))
    surface = estimate_normals(scan, neighbours=7, radius=0.5, min_neighbours=3)
    assert surface.valid.all()
    np.testing.assert_allclose(surface.normals, np.tile([0.0, -1.0], (len(xs), 1)),
                               atol=1e-12)          # towards the sensor at the origin
    assert np.abs(surface.curvature).max() < 1e-12
    # The same line seen from above the line: the normals flip.
    above = estimate_normals(_points(scan.points), 7, 0.5, 3, sensor_origin=[0.0, 5.0])
    np.testing.assert_allclose(above.normals[:, 1], 1.0, atol=1e-12)


def test_normals_and_curvature_of_a_circle():
    radius, count, half = 3.0, 720, 3           # 0.5 degree steps, 7 neighbours
    phi = np.arange(count) * (2.0 * math.pi / count)
    points = radius * np.column_stack((np.cos(phi), np.sin(phi)))
    surface = estimate_normals(_points(points), 2 * half + 1, 1.0, 3)
    np.testing.assert_allclose(surface.normals, -points / radius, atol=1e-9)
    # Neighbours at angles j * d, j = -3..3 around each point: in the radial /
    # tangential frame they are (R cos(j d), R sin(j d)), uncorrelated by symmetry.
    angles = np.arange(-half, half + 1) * (2.0 * math.pi / count)
    radial = np.var(radius * np.cos(angles))
    tangential = np.var(radius * np.sin(angles))
    expected = radial / (radial + tangential)
    np.testing.assert_allclose(surface.curvature, expected, rtol=1e-6)
    # Sampled at the same spacing, a circle half as large bends twice as much over a
    # neighbourhood: the curvature (about (j d)^2 / 4 / ...) grows about 4x.
    small = estimate_normals(_points(points[::2] / 2.0), 2 * half + 1, 1.0, 3)
    assert 3.9 < small.curvature.mean() / surface.curvature.mean() < 4.1


def test_normals_and_curvature_at_a_corner():
    step, arm, half = 0.05, 20, 3
    wall_a = np.column_stack((1.0 - step * np.arange(arm + 1), np.ones(arm + 1)))
    wall_b = np.column_stack((np.ones(arm), 1.0 - step * np.arange(1, arm + 1)))
    points = np.vstack((wall_a, wall_b))        # corner (1, 1) is row 0
    surface = estimate_normals(_points(points), 2 * half + 1, 1.0, 3)
    # Far from the corner each wall is flat with its own normal.
    far_a = np.arange(half + 1, arm + 1)
    far_b = arm + 1 + np.arange(half, arm)
    np.testing.assert_allclose(surface.normals[far_a], [[0.0, -1.0]] * len(far_a), atol=1e-9)
    np.testing.assert_allclose(surface.normals[far_b], [[-1.0, 0.0]] * len(far_b), atol=1e-9)
    assert surface.curvature[far_a].max() < 1e-12 and surface.curvature[far_b].max() < 1e-12
    # At the corner: 3 points on each arm. Along the bisector u the offsets are
    # -j s / sqrt(2) on both arms, across it (v) +-j s / sqrt(2); u is the thin axis.
    j = np.arange(1, half + 1) * step / math.sqrt(2.0)
    u = np.concatenate(([0.0], -j, -j))
    v = np.concatenate(([0.0], -j, j))
    expected = np.var(u) / (np.var(u) + np.var(v))
    assert math.isclose(surface.curvature[0], expected, rel_tol=1e-9)
    np.testing.assert_allclose(surface.normals[0], [-math.sqrt(0.5), -math.sqrt(0.5)],
                               atol=1e-9)
    assert surface.curvature[0] > 0.2


def test_isolated_points_have_no_normal_and_results_are_cached():
    xs = np.arange(0.0, 1.0, 0.02)
    points = np.vstack((np.column_stack((xs, np.ones_like(xs))), [[5.0, 5.0]]))
    scan = _points(points)
    surface = estimate_normals(scan, 6, 0.3, 4)
    assert surface.valid[:-1].all() and not surface.valid[-1]
    np.testing.assert_array_equal(surface.normals[-1], [0.0, 0.0])
    assert estimate_normals(scan, 6, 0.3, 4) is surface


def test_extent_adapts_the_neighbourhood_to_the_sampling():
    dense = np.arange(0.0, 1.0, 0.01)                 # 1 cm spacing
    sparse = 3.0 + np.arange(8) * 0.3                 # 30 cm spacing
    xs = np.concatenate((dense, sparse))
    scan = _points(np.column_stack((xs, np.full_like(xs, 2.0))))
    surface = estimate_normals(scan, neighbours=30, radius=1.0, min_neighbours=3,
                               extent=0.055)
    # Dense: all points within 5.5 cm (11 in the middle); sparse: only the 3 nearest.
    assert surface.count[50] == 11
    assert (surface.count[len(dense):] == 3).all()
    assert surface.valid.all()
    # One query, sliced, gives the same result as a separate estimate.
    distance, index = scan.bearing_index.k_nearest(scan.points, 30, 1.0)
    far = distance[:, 3:]
    far[far > 0.055] = np.inf
    again = normals_from_neighbours(scan, distance, index, 3)
    np.testing.assert_array_equal(again.count, surface.count)
    np.testing.assert_allclose(again.covariance, surface.covariance, atol=1e-15)


def test_normal_variance_predicts_the_scatter_of_noisy_normals():
    rng = np.random.default_rng(2)
    xs = np.arange(-0.1, 0.1001, 0.02)               # 11 points on a wall
    angles, predicted = [], []
    for _ in range(400):
        points = np.column_stack((xs, 2.0 + rng.normal(0.0, 0.01, xs.size)))
        surface = estimate_normals(_points(points), 11, 1.0, 3)
        angles.append(math.atan2(surface.normals[5, 0], -surface.normals[5, 1]))
        predicted.append(normal_variance(surface.covariance[5:6], surface.count[5:6])[0])
    assert 0.7 < np.mean(predicted) / np.var(angles) < 1.4


# --- information --------------------------------------------------------------------

def test_point_information_is_strong_across_a_wall_and_weak_along_it():
    xs = np.arange(-1.0, 1.0 + 1e-9, 0.02)
    line = _points(np.column_stack((xs, np.ones_like(xs))))
    est = estimate_normals(line, 7, 0.5, 3)
    sigma, tau = 0.01, 1.0
    flat = point_information(est.covariance, est.normals, np.ones(len(xs), bool), sigma, tau)
    curved = point_information(est.covariance, est.normals, np.zeros(len(xs), bool), sigma,
                               tau)
    spread = est.covariance[:, 0, 0]            # the neighbours' variance along x
    # [xx, xy, yy]: x runs along the wall, y across it.
    np.testing.assert_allclose(flat[:, 2], 1.0 / sigma ** 2)
    np.testing.assert_allclose(flat[:, 0], 1.0 / (spread + sigma ** 2 + tau ** 2))
    np.testing.assert_allclose(curved[:, 0], 1.0 / (spread + sigma ** 2))
    np.testing.assert_allclose(flat[:, 1], 0.0, atol=1e-9)
    assert flat[:, 0].max() < 1e-3 * flat[:, 2].min()


# --- correspondence rules ----------------------------------------------------------

def _rule_setup():
    """Return a reference wall y = 1 (x in [-1, 1]) with an isolated point, its surface."""
    xs = np.arange(-1.0, 1.0 + 1e-9, 0.02)
    points = np.vstack((np.column_stack((xs, np.ones_like(xs))), [[3.0, 3.0]]))
    reference = _points(points)
    config = NicpConfig()
    surface = nicp_surface(reference, config.surface_settings())
    return reference, surface, config


def _candidates(surface):
    """Six current points (already moved), each breaking at most one rule."""
    wall_normal = np.array([0.0, -1.0])
    moved = np.array([[0.0, 1.0],     # 0: control, passes every rule
                      [0.2, 1.0],     # 1: its own normal is undefined
                      [2.95, 3.0],    # 2: nearest reference point has no normal
                      [0.4, 1.3],     # 3: 0.3 m from the wall
                      [0.6, 1.0],     # 4: normal 60 degrees off
                      [-0.4, 1.0]])   # 5: curved (a corner) against a flat wall
    turned = np.array([math.sin(math.radians(60.0)), -math.cos(math.radians(60.0))])
    normals = np.array([wall_normal, wall_normal, [0.0, -1.0], wall_normal, turned,
                        wall_normal])
    flat = math.log(NicpConfig().curvature_floor)
    log_curvature = np.array([flat, flat, flat, flat, flat, math.log(0.25)])
    usable = np.array([True, False, True, True, True, True])
    return moved, normals, log_curvature, usable


def test_each_rejection_rule_drops_the_pair_it_should():
    reference, surface, config = _rule_setup()
    moved, normals, log_curvature, usable = _candidates(surface)
    distance, index = reference.bearing_index.nearest(moved, np.inf)
    rules = pair_rules(surface, index, distance, normals, log_curvature, usable,
                       max_distance=0.2, min_normal_cosine=math.cos(0.5),
                       max_curvature_ratio=1.5)
    # An undefined reference normal has no angle to compare either (2 fails both).
    expected_failures = {'normal': {1, 2}, 'distance': {3}, 'angle': {2, 4}, 'curvature': {5}}
    for rule, failing in expected_failures.items():
        assert set(np.flatnonzero(~rules[rule])) == failing, rule
    kept, ref_index = associate(reference.bearing_index, surface, moved, normals, log_curvature,
                                usable, 0.2, math.cos(0.5), 1.5)
    assert kept.tolist() == [0]
    assert ref_index.tolist() == [50]           # the wall sample at x = 0


def test_relaxed_thresholds_keep_the_pairs_again():
    reference, surface, config = _rule_setup()
    moved, normals, log_curvature, usable = _candidates(surface)
    kept, _ = associate(reference.bearing_index, surface, moved, normals, log_curvature, usable,
                        max_distance=0.5, min_normal_cosine=math.cos(1.2),
                        max_curvature_ratio=4.0)
    # Only the undefined normals stay out: that rule has no threshold.
    assert kept.tolist() == [0, 3, 4, 5]


# --- Jacobians and normal equations --------------------------------------------------

def _random_pairs(rng: np.random.Generator, count: int = 25):
    angles = rng.uniform(-math.pi, math.pi, (2, count))
    points = rng.uniform(-5.0, 5.0, (count, 2))
    normals = np.column_stack((np.cos(angles[0]), np.sin(angles[0])))
    ref_points = points + rng.normal(0.0, 0.1, (count, 2))
    ref_normals = np.column_stack((np.cos(angles[1]), np.sin(angles[1])))
    return points, normals, ref_points, ref_normals


def test_jacobians_match_finite_differences():
    rng = np.random.default_rng(7)
    points, normals, ref_points, ref_normals = _random_pairs(rng)
    pose = se2.pose(0.3, -0.7, 0.9)
    _, jacobians = residuals_and_jacobians(pose, points, normals, ref_points, ref_normals)
    eps = 1e-6
    for k in range(3):
        delta = np.zeros(3)
        delta[k] = eps
        plus, _ = residuals_and_jacobians(pose + delta, points, normals, ref_points,
                                          ref_normals)
        minus, _ = residuals_and_jacobians(pose - delta, points, normals, ref_points,
                                           ref_normals)
        np.testing.assert_allclose(jacobians[:, :, k], (plus - minus) / (2.0 * eps),
                                   atol=1e-8)


def test_structured_normal_equations_equal_the_dense_ones():
    rng = np.random.default_rng(11)
    points, normals, ref_points, ref_normals = _random_pairs(rng)
    pose = se2.pose(-0.2, 0.4, -1.3)
    error, jacobians = residuals_and_jacobians(pose, points, normals, ref_points,
                                               ref_normals)
    half = rng.normal(size=(len(points), 2, 2))
    spd = half @ np.transpose(half, (0, 2, 1)) + 0.1 * np.eye(2)
    info_point = np.column_stack((spd[:, 0, 0], spd[:, 0, 1], spd[:, 1, 1]))
    info_normal = rng.uniform(1.0, 100.0, len(points))
    weights = rng.uniform(0.1, 1.0, len(points))
    omega = dense_information(info_point, info_normal)
    dense_h = np.einsum('n,nai,nab,nbj->ij', weights, jacobians, omega, jacobians)
    dense_g = np.einsum('n,nai,nab,nb->i', weights, jacobians, omega, error)
    rot = se2.rotation(pose[2])
    np.testing.assert_allclose(error, np.hstack((points @ rot.T + pose[:2] - ref_points,
                                                 normals @ rot.T - ref_normals)), atol=1e-12)
    hessian, gradient = normal_equations(points @ rot.T, normals @ rot.T, error[:, :2],
                                         error[:, 2:], info_point, info_normal, weights)
    np.testing.assert_allclose(hessian, dense_h, rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(gradient, dense_g, rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(chi_squared(error[:, :2], error[:, 2:], info_point, info_normal),
                               np.einsum('na,nab,nb->n', error, omega, error), rtol=1e-12)


def test_rule_boundaries_are_inclusive():
    # Each rule at its exact threshold passes, just beyond it fails: a distance of
    # 0.25 m, a cosine of 0.6 (normals (1, 0) and (0.6, 0.8)) and a curvature ratio of
    # 2 (|log 0.25 - log 1| = log 4 at max_curvature_ratio log 4).
    ref_normals = np.array([[0.6, 0.8], [0.6, 0.8], [1.0, 0.0]])
    ref_log_curvature = np.log([1.0, 1.0, 1.0])
    rotated = np.array([[1.0, 0.0], [0.6, 0.8], [0.6, 0.8], [0.0, 1.0], [0.6, 0.8],
                        [0.6, 0.8]])
    log_curvature = np.log([1.0, 1.0, 1.0, 1.0, 0.25, 0.2499])
    index = np.array([0, 1, 2, 2, 1, 1])
    distance = np.array([0.25, 0.2501, 0.1, 0.1, 0.1, 0.1])
    table = rule_table(ref_normals, ref_log_curvature, np.ones(3, bool), index, distance,
                       rotated, log_curvature, np.ones(6, bool), 0.25, 0.6, math.log(4.0))
    np.testing.assert_array_equal(table, [[True, True, True, True],
                                          [True, False, True, True],
                                          [True, True, True, True],     # cosine 0.6
                                          [True, True, False, True],    # cosine 0
                                          [True, True, True, True],
                                          [True, True, True, False]])


def _linearise(reference: ScanPoints, current: ScanPoints, estimate: se2.Pose,
               count: int | None = None) -> tuple:
    """Linearise NICP with the default settings, as the matcher does (first ``count``)."""
    cfg = NicpConfig()
    ref = nicp_surface(reference, cfg.surface_settings())
    cur = nicp_surface(current, cfg.surface_settings())
    index = reference.bearing_index
    chosen = slice(0, count)
    system = linearise(
        index.sorted_points, index.bearings, index.directions, index.order, ref.points,
        ref.normals, ref.log_curvature, ref.usable, ref.info_point, ref.info_normal,
        cur.points_usable[chosen], cur.normals_usable[chosen],
        cur.log_curvature_usable[chosen], np.asarray(estimate, dtype=float),
        cfg.max_correspondence_distance, math.cos(cfg.max_normal_angle),
        cfg.max_curvature_ratio, kernel_code(cfg.robust_kernel), cfg.robust_scale)
    return system, ref, cur, cfg


@pytest.mark.parametrize('count', [None, 3])
def test_linearisation_reports_the_surface_distance_and_the_variance_factor(count):
    # The RMS point-to-line distance of the pairs (along the reference normal), and the
    # a-posteriori variance factor sum w e^T Omega e / max(sum w - 3, 1) with the robust
    # weights of the Mahalanobis errors; three pairs give fewer than 1 degree of freedom.
    reference = _scan(ROOM, START, LaserModel(beams=360, fov=2.0 * math.pi, max_range=20.0,
                                              noise_sigma=0.01), seed=4)
    current = _moved_copy(reference, se2.pose(0.1, -0.05, 0.02))
    estimate = se2.pose(0.09, -0.04, 0.025)
    system, ref, cur, cfg = _linearise(reference, current, estimate, count)
    pairs, residual, variance_factor = system[0], system[3], system[4]
    ref_index, weights = system[9], system[10]
    moved = se2.transform_points(estimate, cur.points_usable[:count])
    rotated_normals = cur.normals_usable[:count] @ se2.rotation(estimate[2]).T
    picked, expected_index = associate(
        reference.bearing_index, ref, moved, rotated_normals,
        cur.log_curvature_usable[:count], np.ones(len(moved), bool),
        cfg.max_correspondence_distance, math.cos(cfg.max_normal_angle),
        cfg.max_curvature_ratio)
    np.testing.assert_array_equal(ref_index, expected_index)
    assert pairs == len(picked)
    assert pairs == 3 if count else pairs > 200
    point_error = moved[picked] - ref.points[ref_index]
    normal_error = rotated_normals[picked] - ref.normals[ref_index]
    along = np.einsum('nd,nd->n', point_error, ref.normals[ref_index])
    assert residual == pytest.approx(math.sqrt(np.mean(along ** 2)), rel=1e-12)
    assert residual > 1e-3
    omega = dense_information(ref.info_point[ref_index], ref.info_normal[ref_index])
    error = np.hstack((point_error, normal_error))
    chi2 = np.einsum('na,nab,nb->n', error, omega, error)
    np.testing.assert_allclose(
        weights, kernel_weights(np.sqrt(chi2), kernel_code(cfg.robust_kernel),
                                cfg.robust_scale), rtol=1e-12)
    assert variance_factor == pytest.approx(
        weights @ chi2 / max(weights.sum() - 3.0, 1.0), rel=1e-12)
    assert (weights.sum() < 4.0) == bool(count)


# --- recovery ------------------------------------------------------------------------

@pytest.mark.parametrize('truth, guess', [
    (se2.pose(0.12, -0.05, 0.04), se2.pose()),
    (se2.pose(-0.25, 0.15, -0.12), se2.pose(-0.1, 0.1, -0.05)),
    (se2.pose(0.3, 0.2, 0.2), se2.pose(0.25, 0.1, -0.25)),    # 0.45 rad off: restart
])
def test_exact_recovery_on_noise_free_scans(truth, guess):
    reference = _scan(ROOM, START)
    current = _moved_copy(reference, truth)
    result = create_matcher('nicp').match(reference, current, guess)
    assert result.converged
    error = se2.relative(truth, result.pose)
    assert math.hypot(error[0], error[1]) < 1e-6
    assert abs(error[2]) < 1e-6
    assert result.residual < 1e-4             # measured before the last (tiny) step
    assert result.inlier_ratio > 0.95
    assert not result.degenerate


def test_recovery_between_two_ray_cast_scans():
    """Match scans whose beams sample the walls differently (only sampling limits it)."""
    truth = se2.pose(0.2, -0.1, 0.08)
    reference = _scan(ROOM, START)
    current = _scan(ROOM, se2.compose(START, truth))
    result = create_matcher('nicp').match(reference, current, se2.pose())
    assert result.converged
    error = se2.relative(truth, result.pose)
    assert math.hypot(error[0], error[1]) < 2e-3
    assert abs(error[2]) < math.radians(0.05)


def test_rotation_seed_finds_the_turn_from_normal_histograms():
    reference = _scan(ROOM, START)
    current = _moved_copy(reference, se2.pose(0.1, 0.05, 0.35))
    settings = NicpConfig().surface_settings()
    theta = rotation_seed(nicp_surface(reference, settings), nicp_surface(current, settings),
                          0.0, 0.6)
    assert abs(theta - 0.35) < math.radians(0.5)


def test_only_flips_between_pairings_count_as_oscillation():
    step = np.array([1e-3, -2e-3, 5e-4])
    assert undoes(-step, step)                       # a flip back
    assert undoes(-0.6 * step, step)
    assert not undoes(-0.1 * step, step)             # a Gauss-Newton overshoot fix
    assert not undoes(step, step)
    assert not undoes(np.array([2e-3, 1e-3, 0.0]), step)   # orthogonal


def turned_step(length: float, degrees: float) -> np.ndarray:
    """Return a step of ``length`` at ``degrees`` from the x axis (no rotation)."""
    return length * np.array([math.cos(math.radians(degrees)),
                              math.sin(math.radians(degrees)), 0.0])


def test_a_flip_is_over_120_degrees_back_and_at_least_half_as_long():
    previous = turned_step(1e-3, 0.0)
    assert undoes(turned_step(1e-3, 121.0), previous)
    assert not undoes(turned_step(1e-3, 119.0), previous)
    assert undoes(turned_step(0.51e-3, 180.0), previous)
    assert not undoes(turned_step(0.49e-3, 180.0), previous)
    assert undoes(turned_step(3e-3, 180.0), previous)  # longer counts too
    assert not undoes(turned_step(1e-3, 180.0), np.zeros(3))  # no previous step


def test_damped_step_solves_the_damped_normal_equations():
    """(H + mu diag H) dx = -g (NICP's fixed relative damping), by Cramer's rule."""
    rng = np.random.default_rng(5)
    a = rng.normal(size=(3, 3))
    hessian = a @ a.T + np.diag([3.0, 1.0, 0.5])
    gradient = rng.normal(size=3)
    for damping in (0.0, 0.1, 2.0):
        expected = -np.linalg.solve(hessian + damping * np.diag(np.diag(hessian)), gradient)
        assert damped_step(hessian, gradient, damping) == pytest.approx(expected, rel=1e-12)
    asymmetric = hessian + np.array([[0.0, 0.3, -0.2], [0.1, 0.0, 0.4], [0.5, -0.1, 0.0]])
    assert damped_step(asymmetric, gradient, 0.0) == pytest.approx(
        -np.linalg.solve(asymmetric, gradient), rel=1e-12)
    assert np.array_equal(hessian, a @ a.T + np.diag([3.0, 1.0, 0.5]))  # left unchanged


def test_a_singular_or_non_finite_system_gives_no_step():
    singular = np.diag([1.0, 1.0, 0.0])  # nothing constrains the heading
    assert np.isnan(damped_step(singular, np.ones(3), 0.5)).all()
    infinite = np.diag([1.0, np.inf, 1.0])
    assert np.isnan(damped_step(infinite, np.ones(3), 0.0)).all()


def test_too_few_points_fail_cleanly():
    reference = _scan(ROOM, START)
    result = create_matcher('nicp').match(reference, _points(reference.points[:5]),
                                          se2.pose())
    assert not result.converged
    np.testing.assert_array_equal(result.pose, se2.pose())


# --- degeneracy -----------------------------------------------------------------------

def test_featureless_corridor_is_degenerate_along_its_axis():
    laser = LaserModel(beams=360, fov=2.0 * math.pi, max_range=8.0, noise_sigma=0.005)
    reference = _scan(CORRIDOR, se2.pose(), laser, seed=1)
    current = _scan(CORRIDOR, se2.pose(0.1, 0.0, 0.0), laser, seed=2)
    result = create_matcher('nicp').match(reference, current, se2.pose(0.1, 0.0, 0.0))
    assert result.converged
    assert result.degenerate
    covariance = result.covariance
    assert covariance[0, 0] >= 10.0 * covariance[1, 1]
    values, vectors = np.linalg.eigh(result.information)
    assert abs(vectors[0, 0]) > 0.99             # the weakest direction is x
    assert abs(result.pose[1]) < 5e-3 and abs(result.pose[2]) < 2e-3


def test_corridor_match_converges_instead_of_creeping_along_the_axis():
    laser = LaserModel(beams=360, fov=2.0 * math.pi, max_range=8.0, noise_sigma=0.005)
    reference = _scan(CORRIDOR, se2.pose(), laser, seed=1)
    current = _scan(CORRIDOR, se2.pose(0.1, 0.0, 0.0), laser, seed=2)
    config = NicpConfig(restart_window=0.0)
    result = NicpMatcher(config).match(reference, current, se2.pose(0.1, 0.0, 0.0))
    assert result.converged and result.iterations < 15
    strict = NicpMatcher(NicpConfig(restart_window=0.0, convergence_chi2=0.0))
    assert strict.match(reference, current, se2.pose(0.1, 0.0, 0.0)).iterations >= \
        result.iterations


def test_room_is_not_degenerate():
    laser = LaserModel(beams=360, fov=2.0 * math.pi, max_range=20.0, noise_sigma=0.01)
    reference = _scan(ROOM, START, laser, seed=3)
    current = _scan(ROOM, se2.compose(START, se2.pose(0.1, 0.0, 0.05)), laser, seed=4)
    result = create_matcher('nicp').match(reference, current, se2.pose(0.1, 0.0, 0.05))
    assert result.converged and not result.degenerate
    sigma = np.sqrt(np.diag(result.covariance))
    assert sigma[0] < 0.02 and sigma[1] < 0.02 and sigma[2] < math.radians(0.5)


# --- registration and configuration ------------------------------------------------

def test_registered_with_validated_parameters():
    assert 'nicp' in matcher_names()
    assert isinstance(create_matcher('nicp'), NicpMatcher)
    assert isinstance(default_config('nicp'), NicpConfig)
    assert create_matcher('nicp', {'point_sigma': 0.02}).config.point_sigma == 0.02
    with pytest.raises(ParameterError):
        create_matcher('nicp', {'max_normal_angle': -1.0})
    with pytest.raises(ParameterError):
        create_matcher('nicp', {'robust_kernel': 'bogus'})


def test_yaml_restates_the_tuned_defaults():
    document = yaml.safe_load(CONFIG_FILE.read_text())
    params = document['/**']['ros__parameters']
    assert params['matcher'] == 'nicp'
    assert params['nicp'] == as_dict(NicpConfig())
    flat = {'matcher': 'nicp', **{f'nicp.{k}': v for k, v in params['nicp'].items()}}
    config = pipeline_config_from_params(flat)
    assert config.matcher == 'nicp' and config.matcher_config == NicpConfig()


# --- real data (skipped without ../shared/data) ----------------------------------------

@pytest.mark.parametrize('path, scans, bounds', [
    # (mean RPE [m], mean RPE [deg], ATE [m]) on the first scans, constant velocity
    ('mit-csail/mit-csail.clf', 500, (0.025, 0.45, 0.2)),
    ('fr079/freiburg-079-corrected.log.gz', 600, (0.025, 0.3, 0.2)),
])
def test_real_logs_are_tracked(shared_data_dir, path, scans, bounds):
    dataset = load_dataset(shared_data_dir / path)
    pipeline = OdometryPipeline(PipelineConfig(matcher='nicp'),
                                events=EventLog(lambda message: None))
    errors = evaluate(run_pipeline(pipeline, dataset.scans[:scans]).trajectory,
                      dataset.reference)
    assert errors.steps > 100 and errors.failed_steps == 0
    assert errors.rpe_trans_mean < bounds[0]
    assert errors.rpe_rot_mean < bounds[1]
    assert errors.ate_rms < bounds[2]


def test_iterations_are_counted_from_one_and_capped():
    """The cap is the last iteration run: one fewer leaves the match unconverged.

    One stage (no capture stage): the cap is per stage, the count their sum.
    """
    laser = LaserModel(beams=360, fov=2.0 * math.pi, max_range=20.0, noise_sigma=0.005)
    reference = _scan(ROOM, START, laser, seed=1)
    motion = se2.pose(0.15, 0.05, 0.08)
    current = _scan(ROOM, se2.compose(START, motion), laser, seed=2)

    def match(cap: int):
        config = NicpConfig(restart_window=0.0, max_iterations=cap, capture_distance=0.0)
        return NicpMatcher(config).match(reference, current, se2.pose())

    free = match(100)
    assert free.converged and free.iterations >= 3
    assert np.hypot(*(free.pose - motion)[:2]) < 0.01
    capped = match(free.iterations)
    assert capped.converged and capped.iterations == free.iterations
    assert np.array_equal(capped.pose, free.pose)
    short = match(free.iterations - 1)
    assert not short.converged and short.iterations == free.iterations - 1
    assert not np.array_equal(short.pose, free.pose)


def test_the_capture_stage_finds_a_step_longer_than_the_pair_gate_along_a_corridor():
    """From zero motion, a 1 m step along the simulated corridors (180 deg, 361 beams).

    Within the 0.5 m pair gate only the side walls pair, which say nothing along the
    corridor: the match stays where it started. Pairs up to ``capture_distance`` (1.5
    m) first reach the door frames and the corridor's ends.
    """
    world = get_world('corridor')
    laser = LaserModel(beams=361, fov=math.pi)
    rng = np.random.default_rng(0)
    motion = se2.pose(1.0, 0.0, 0.0)
    found = {}
    for name, config in (('capture', NicpConfig()),
                         ('gate only', NicpConfig(capture_distance=0.0))):
        found[name] = 0
        for t in np.arange(2.0, 120.0, 4.0):
            start = world.path.poses_at(np.array([t]))[0]
            reference = scan_to_points(render_scan(world, start, laser, rng))
            current = scan_to_points(render_scan(world, se2.compose(start, motion), laser,
                                                 rng))
            error = se2.relative(motion, NicpMatcher(config).match(reference, current,
                                                                   se2.pose()).pose)
            found[name] += math.hypot(error[0], error[1]) < 0.05
    assert found['capture'] >= 20 and found['gate only'] <= 5, found  # of 30 pairs
    # A trusted prediction is refined within the pair gate alone: no capture stage.
    prediction = se2.pose(0.95, 0.02, 0.01)
    refined = NicpMatcher().match_from_prediction(reference, current, prediction)
    gated = NicpMatcher(NicpConfig(capture_distance=0.0))
    gated = gated.match(reference, current, prediction)
    np.testing.assert_array_equal(refined.pose, gated.pose)
    error = se2.relative(motion, refined.pose)
    assert math.hypot(error[0], error[1]) < 0.05


# Last in the file: the slowest self-contained test here (8 s with numba off), and a
# mutation run (.ci/mutation.py) stops a mutant at its first failing test.
def test_debiased_information_does_not_claim_the_axis_of_a_straight_wall():
    """Check that debiasing removes the along-wall weight that noisy normals leak."""
    rng = np.random.default_rng(5)
    xs = np.arange(-2.0, 2.0, 0.01)
    sigma, tau = 0.01, 3.0
    naive, debiased = [], []
    for _ in range(100):
        points = np.column_stack((xs, 1.0 + rng.normal(0.0, sigma, xs.size)))
        est = estimate_normals(_points(points), 20, 0.5, 3)
        flat = np.ones(xs.size, bool)
        naive.append(point_information(est.covariance, est.normals, flat, sigma,
                                       tau)[:, 0].sum())
        debiased.append(point_information(est.covariance, est.normals, flat, sigma, tau,
                                          normal_variance(est.covariance, est.count))[:, 0].sum())
    along = xs.size / tau ** 2                       # what the wall really holds along x
    bias = np.mean(naive) - along
    assert bias > 50.0 * along                       # the leak dwarfs the real weight
    assert abs(np.mean(debiased) - along) < 0.15 * bias
