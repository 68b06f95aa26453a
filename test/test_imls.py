"""Tests of the IMLS-ICP matcher: the implicit surface, selection, recovery, information."""

from dataclasses import replace
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import pipeline_config_from_params, PipelineConfig
from laser_odom.core.datasets import load_dataset
from laser_odom.core.evaluation.metrics import evaluate
from laser_odom.core.matchers import create_matcher, default_config, matcher_names
from laser_odom.core.matchers.base import MatchResult
from laser_odom.core.matchers.imls.matcher import (
    ALIGNED_COSINE, COARSE_FRACTION, COARSE_SHARE, ImlsConfig, ImlsMatcher, MAX_GAIN)
from laser_odom.core.matchers.imls.solver import (
    advance, fuse_directions, gauss_newton_step, inverted_information, point_to_plane_system,
    step_cosine, surface_information)
from laser_odom.core.matchers.imls.surface import (
    candidate_ranking, implicit_surface, model_from_arrays, observability_scores, planarity,
    project_onto_surface, select_on_surface, surface_model, SurfaceSample)
from laser_odom.core.matchers.information import (
    debiased_point_to_line_information, point_to_line_information)
from laser_odom.core.matchers.robust import inlier_mask, kernel_code, kernel_weights
from laser_odom.core.parameters import as_dict, ParameterError
from laser_odom.core.pipeline.odometry import OdometryPipeline
from laser_odom.core.pipeline.runner import run_pipeline
from laser_odom.core.scan.laser_scan import scan_to_points, ScanPoints
from laser_odom.core.simulation import geometry as geo, get_world, LaserModel, render_scan, World

CONFIG_FILE = Path(__file__).resolve().parents[1] / 'config' / 'imls.yaml'
H = 0.1
RADIUS = 0.3

# An irregular room (no symmetry that would make a pose ambiguous) with a pillar and
# a box, so every degree of freedom is constrained.
ROOM = World(
    'imls-room', 'irregular polygon room for the IMLS tests',
    geo.stack(geo.polygon([[-4.0, -3.0], [5.0, -3.5], [6.0, 1.0], [3.5, 4.0], [-2.0, 3.5],
                           [-4.5, 1.0]]),
              geo.box(2.0, 1.5, 0.8, 0.5, 0.4), geo.pillar(-2.0, -1.0, 0.3)),
    np.zeros((2, 2)))

# A 2 m wide corridor closed at x = 7 and open (beyond range) behind the robot: only
# the end wall tells where along the corridor the robot is.
CORRIDOR = World(
    'imls-corridor', 'corridor with an end wall and a corner',
    geo.stack(geo.wall((-30.0, -1.0), (7.0, -1.0)), geo.wall((-30.0, 1.0), (4.0, 1.0)),
              geo.wall((4.0, 1.0), (4.0, 3.0)), geo.wall((4.0, 3.0), (7.0, 3.0)),
              geo.wall((7.0, -1.0), (7.0, 3.0))),
    np.zeros((2, 2)))

EXACT = LaserModel(beams=360, fov=2.0 * math.pi, max_range=20.0, noise_sigma=0.0)


def _scan(world: World, pose: se2.Pose, laser: LaserModel = EXACT, seed: int = 0,
          stamp_ns: int = 0) -> ScanPoints:
    scan = render_scan(world, pose, laser, np.random.default_rng(seed), stamp_ns)
    return scan_to_points(scan)


def _line_model(spacing: float = 0.01):
    xs = np.arange(-5.0, 5.0 + 1e-9, spacing)
    points = np.column_stack((xs, np.zeros_like(xs)))
    normals = np.tile([0.0, 1.0], (len(xs), 1))
    return model_from_arrays(points, normals)


def _circle_model(radius: float, spacing: float = 0.005):
    count = int(round(2.0 * math.pi * radius / spacing))
    phi = np.arange(count) * (2.0 * math.pi / count)
    points = radius * np.column_stack((np.cos(phi), np.sin(phi)))
    return model_from_arrays(points, -points / radius)   # normals towards the centre


def test_surface_is_signed_distance_to_a_straight_wall():
    model = _line_model()
    rng = np.random.default_rng(1)
    queries = np.column_stack((rng.uniform(-3.0, 3.0, 200), rng.uniform(-0.25, 0.25, 200)))
    sample = implicit_surface(model, queries, H, RADIUS, 32, 3)
    assert sample.defined.all()
    np.testing.assert_allclose(sample.value, queries[:, 1], atol=1e-9)
    np.testing.assert_allclose(sample.normal, np.tile([0.0, 1.0], (200, 1)))


def test_surface_is_signed_distance_to_a_circle_up_to_the_smoothing_error():
    # For inward normals, I(x) = (R - |x|) + h^2 / (4 R) to first order: the Gaussian
    # weights spread over an arc of angular variance h^2 / (2 R |x|) (Kolluri 2005).
    radius = 2.0
    model = _circle_model(radius)
    rng = np.random.default_rng(2)
    rho = radius + rng.uniform(-0.15, 0.15, 300)
    phi = rng.uniform(-math.pi, math.pi, 300)
    queries = rho[:, None] * np.column_stack((np.cos(phi), np.sin(phi)))
    sample = implicit_surface(model, queries, H, RADIUS, 200, 3)
    assert sample.defined.all()
    signed = radius - rho
    smoothing = H * H / (4.0 * radius)
    assert np.max(np.abs(sample.value - signed)) < 2.0 * smoothing
    np.testing.assert_allclose(sample.value, signed + smoothing, atol=0.15 * smoothing)


def test_surface_from_estimated_normals_of_a_scanned_wall():
    # A wall 2 m in front of the sensor, scanned at 0.25 deg: normals come from
    # estimate_normals and point back at the sensor, so I > 0 on the sensor's side.
    angles = np.radians(np.arange(-40.0, 40.0, 0.25))
    ranges = 2.0 / np.cos(angles)
    points = np.column_stack((ranges * np.cos(angles), ranges * np.sin(angles)))
    scan = ScanPoints(points, np.arange(len(points)), ranges)
    model = surface_model(scan, 10, 0.3, 4)
    queries = np.column_stack((np.linspace(1.8, 2.2, 41), np.linspace(-1.0, 1.0, 41)))
    sample = implicit_surface(model, queries, H, RADIUS, 16, 3)
    assert sample.defined.all()
    np.testing.assert_allclose(sample.value, 2.0 - queries[:, 0], atol=1e-6)
    assert surface_model(scan, 10, 0.3, 4) is model          # cached on the scan


def test_points_with_too_few_neighbours_have_no_surface_value():
    model = _line_model(spacing=0.2)
    queries = np.array([[0.0, 0.05], [0.0, 1.0], [100.0, 0.0]])
    sample = implicit_surface(model, queries, H, RADIUS, 8, 3)
    # (0, 0.05) has 3 points within 0.3 m (x = -0.2, 0, 0.2); the others have none.
    np.testing.assert_array_equal(sample.defined, [True, False, False])
    np.testing.assert_array_equal(sample.count, [3, 0, 0])
    assert sample.value[1] == 0.0 and not sample.normal[1].any()
    assert not implicit_surface(model, queries, H, RADIUS, 8, 4).defined.any()


def _surface_by_definition(points, normals, usable, x, h, radius, k):
    """Return IMLS-SLAM eq. 1 at ``x`` in plain numpy.

    The sums run over the usable points among the ``k`` nearest reference points within
    ``radius``; the weights are relative to the nearest one's (the same ratio, no
    underflow far from the surface).
    """
    distance = np.hypot(*(points - x).T)
    near = [j for j in np.argsort(distance)[:k] if distance[j] <= radius and usable[j]]
    if not near:
        return 0.0, np.zeros(2), 0, np.zeros(2), len(points)
    weight = np.exp(-(distance[near] ** 2 - distance[near[0]] ** 2) / h ** 2)
    tangent = np.einsum('nd,nd->n', x - points[near], normals[near])
    mean = weight @ normals[near]
    return (weight @ tangent / weight.sum(), normals[near[0]], len(near),
            mean / np.linalg.norm(mean), near[0])


@pytest.mark.parametrize('h, radius, k, spread, defined', [(0.1, 0.35, 5, 1.3, 171),
                                                           (0.1, 0.35, 1, 1.3, 124),
                                                           (0.05, 3.0, 3, 3.0, 200)])
def test_surface_follows_its_definition_at_random_queries(h, radius, k, spread, defined):
    # Random points, normals and unusable points; one usable neighbour is enough
    # (min_neighbours 1). The second case sums a single neighbour; the last reaches 3 m
    # with a 5 cm kernel: far queries keep a finite surface value.
    rng = np.random.default_rng(7)
    points = rng.uniform(-1.0, 1.0, (60, 2))
    angle = rng.uniform(-math.pi, math.pi, 60)
    normals = np.column_stack((np.cos(angle), np.sin(angle)))
    usable = rng.random(60) > 0.2
    queries = rng.uniform(-spread, spread, (200, 2))
    sample = implicit_surface(model_from_arrays(points, normals, usable), queries, h, radius,
                              k, 1)
    for q, x in enumerate(queries):
        value, normal, count, mean, nearest = _surface_by_definition(
            points, normals, usable, x, h, radius, k)
        assert sample.defined[q] == (count > 0) and sample.count[q] == count
        assert sample.value[q] == pytest.approx(value, abs=1e-12)
        np.testing.assert_allclose(sample.normal[q], normal, atol=1e-12)
        np.testing.assert_allclose(sample.mean_normal[q], mean, atol=1e-12)
        assert sample.nearest[q] == nearest
    assert sample.defined.sum() == defined


def test_projection_lands_on_the_surface():
    line = _line_model()
    rng = np.random.default_rng(3)
    queries = np.column_stack((rng.uniform(-3, 3, 100), rng.uniform(-0.2, 0.2, 100)))
    sample = implicit_surface(line, queries, H, RADIUS, 32, 3)
    projected = project_onto_surface(queries, sample.value, sample.normal)
    np.testing.assert_allclose(projected[:, 1], 0.0, atol=1e-9)
    np.testing.assert_allclose(projected[:, 0], queries[:, 0], atol=1e-9)

    radius = 2.0
    circle = _circle_model(radius)
    phi = rng.uniform(-math.pi, math.pi, 100)
    queries = (radius + rng.uniform(-0.2, 0.2, 100))[:, None] * np.column_stack(
        (np.cos(phi), np.sin(phi)))
    sample = implicit_surface(circle, queries, H, RADIUS, 200, 3)
    projected = project_onto_surface(queries, sample.value, sample.normal)
    # On the IMLS surface itself (I(y) ~ 0): the zero set of (R - |x|) + h^2 / 4R, a
    # circle h^2 / 4R wider than the sampled one.
    again = implicit_surface(circle, projected, H, RADIUS, 200, 3)
    assert np.max(np.abs(again.value)) < 1e-3 * H
    np.testing.assert_allclose(np.hypot(*projected.T), radius + H * H / (4 * radius),
                               atol=2e-4)


def test_planarity_is_one_on_a_line_and_zero_on_a_blob():
    np.testing.assert_allclose(planarity(np.array([0.0, 0.5, 0.2])),
                               [1.0, 0.0, 1.0 - math.sqrt(0.25)])


def test_scores_and_ranking_follow_their_definition():
    # IMLS-SLAM section III-B in 2D: a^2 |n_x|, a^2 |n_y|, +-a^2 (x cross n). Each list
    # holds the usable points of positive score, best first (ties: lower index), then -1.
    rng = np.random.default_rng(11)
    points = rng.uniform(-5.0, 5.0, (40, 2))
    angle = rng.uniform(-math.pi, math.pi, 40)
    normals = np.column_stack((np.cos(angle), np.sin(angle)))
    curvature = rng.uniform(0.0, 0.5, 40)
    curvature[:4] = 0.5                                 # no planarity: no score
    points[30:35], normals[30:35], curvature[30:35] = points[20], normals[20], curvature[20]
    usable = rng.random(40) > 0.2
    usable[30:35] = True
    a2 = planarity(curvature) ** 2
    cross = points[:, 0] * normals[:, 1] - points[:, 1] * normals[:, 0]
    expected = np.column_stack((a2 * np.abs(normals[:, 0]), a2 * np.abs(normals[:, 1]),
                                a2 * cross, -a2 * cross))
    scores = observability_scores(points, normals, curvature)
    np.testing.assert_allclose(scores, expected, rtol=1e-12, atol=1e-15)
    model = model_from_arrays(points, normals, usable)
    model.curvature = np.append(curvature, 0.5)
    ranking = candidate_ranking(model)
    assert ranking.shape == (4, 40)
    for column in range(4):
        listed = [i for i in sorted(range(40), key=lambda i: -expected[i, column])
                  if usable[i] and expected[i, column] > 0.0]
        assert ranking[column].tolist() == listed + [-1] * (40 - len(listed))
        assert 5 < len(listed) < 36


def test_selection_keeps_every_degree_of_freedom_in_a_corridor():
    current = _scan(CORRIDOR, se2.pose(0.0, 0.0, 0.05))
    model = surface_model(current, 10, 0.3, 4)
    normals, usable = model.normals[:-1], model.usable[:-1]
    scores = observability_scores(current.points, normals, model.curvature[:-1])
    per_list = 20
    # Against its own surface every usable point is on it: the lists alone decide.
    chosen, _ = select_on_surface(model, candidate_ranking(model), current.points,
                                  se2.pose(), per_list, H, RADIUS, 4, 2)
    assert np.all(usable[chosen])
    assert len(np.unique(chosen)) == len(chosen)
    assert 3 * per_list <= len(chosen) <= 4 * per_list
    x_facing = np.abs(normals[chosen, 0]) > 0.9
    on_side_walls = np.abs(normals[chosen, 1]) > 0.9
    # The end wall and the corner's short walls are a small part of the scan, yet they
    # fill the x list: the motion along the corridor stays observable.
    assert np.count_nonzero(x_facing) >= per_list
    assert np.count_nonzero(np.abs(normals[usable, 0]) > 0.9) < 0.35 * np.count_nonzero(usable)
    # Not an all-one-wall selection: both long walls contribute.
    ys = current.points[chosen, 1]
    assert np.count_nonzero(on_side_walls & (ys > 0.5)) >= 5
    assert np.count_nonzero(on_side_walls & (ys < -0.5)) >= 5
    # Both signs of rotation are represented.
    assert np.count_nonzero(scores[chosen, 2] > 0.5) >= per_list // 2
    assert np.count_nonzero(scores[chosen, 3] > 0.5) >= per_list // 2
    # Per point, the selection's weakest direction is much better constrained than the
    # whole scan's (rotation measured as the arc at 5 m).

    def weakest(index):
        jac = np.column_stack((normals[index], scores[index, 2] / 5.0))
        return np.linalg.eigvalsh(jac.T @ jac)[0] / len(index)
    assert weakest(chosen) > 2.0 * weakest(np.flatnonzero(usable))


def _selected_by_definition(scores, eligible, per_list):
    """Fill the lists in turn from a full ranking of the eligible points (the spec)."""
    taken = np.zeros(len(eligible), dtype=bool)
    for column in range(scores.shape[1]):
        candidates = np.flatnonzero(eligible & ~taken & (scores[:, column] > 0.0))
        best = candidates[np.argsort(-scores[candidates, column], kind='stable')]
        taken[best[:per_list]] = True
    return np.flatnonzero(taken)


@pytest.mark.parametrize('offset', [se2.pose(0.0, 0.0, 0.0), se2.pose(0.6, -0.3, 0.1),
                                    se2.pose(-1.5, 0.4, -0.3)])
def test_selection_evaluates_the_surface_only_where_the_lists_look(offset):
    # The lazy selection against another scan's surface, moved so that part of the
    # scan falls off the reference: the same points as ranking every point that has a
    # surface value (the whole scan evaluated) and filling the lists in turn.
    reference = _scan(ROOM, se2.pose(0.0, 0.0, 0.0))
    current = _scan(ROOM, se2.pose(0.3, 0.2, 0.15), seed=1)
    ref_model = surface_model(reference, 10, 0.6, 2)
    model = surface_model(current, 10, 0.6, 2)
    pose = se2.compose(se2.pose(0.3, 0.2, 0.15), offset)
    full = implicit_surface(ref_model, se2.transform_points(pose, current.points), H, RADIUS,
                            4, 2)
    scores = observability_scores(current.points, model.normals[:-1], model.curvature[:-1])
    for per_list in (1, 15, 60, 300, 1000):
        chosen, sample = select_on_surface(ref_model, candidate_ranking(model),
                                           current.points, pose, per_list, H, RADIUS, 4, 2)
        expected = _selected_by_definition(scores, model.usable[:-1] & full.defined,
                                           per_list)
        np.testing.assert_array_equal(chosen, expected)
        np.testing.assert_array_equal(sample.value, full.value[chosen])
        np.testing.assert_array_equal(sample.nearest, full.nearest[chosen])
        np.testing.assert_array_equal(sample.normal, full.normal[chosen])
        np.testing.assert_array_equal(sample.mean_normal, full.mean_normal[chosen])
        np.testing.assert_array_equal(sample.count, full.count[chosen])
        assert sample.defined.all()
    assert 0 < np.count_nonzero(~full.defined & model.usable[:-1]) or offset[0] == 0.0


def test_selection_takes_only_ranked_points():
    # 1501 points near a wall, all planar (an analytic model has zero curvature) but the
    # last, which has no normal: no list ranks it, so no list takes it, however long.
    # 300 per list stops the lists short of the 1500 candidates.
    xs = np.linspace(-4.0, 4.0, 1501)
    points = np.column_stack((xs, np.full(1501, 0.01)))
    normals = np.tile([0.6, 0.8], (1501, 1))
    usable = np.arange(1501) < 1500
    ranking = candidate_ranking(model_from_arrays(points, normals, usable))
    assert sorted(ranking[0][ranking[0] >= 0].tolist()) == list(range(1500))
    scores = observability_scores(points, normals, np.zeros(1501))
    for per_list, count in ((300, 1052), (5000, 1500)):
        chosen, sample = select_on_surface(_line_model(), ranking, points, se2.pose(),
                                           per_list, H, RADIUS, 4, 2)
        np.testing.assert_array_equal(chosen, _selected_by_definition(scores, usable, per_list))
        assert len(chosen) == count and sample.defined.all()
    # Against samples 0.5 m apart most points have one neighbour within the radius:
    # enough with min_neighbours 1; with max_neighbours 1 the surface is the nearest
    # sample's tangent line (the samples' normals tilt by turns, so two differ).
    samples = np.column_stack((np.arange(-5.0, 5.01, 0.5), np.zeros(21)))
    tilt = 0.2 * (-1.0) ** np.arange(21)
    sparse = model_from_arrays(samples, np.column_stack((np.sin(tilt), np.cos(tilt))))
    nearest_only = implicit_surface(sparse, points, H, RADIUS, 1, 1)
    reach = nearest_only.defined
    chosen, sample = select_on_surface(sparse, ranking, points, se2.pose(), 300, H, RADIUS, 1,
                                       1)
    np.testing.assert_array_equal(chosen, _selected_by_definition(scores, usable & reach, 300))
    np.testing.assert_array_equal(sample.value, nearest_only.value[chosen])
    pairs = implicit_surface(sparse, points, H, RADIUS, 4, 2).defined   # near midpoints
    assert reach.all() and np.count_nonzero(pairs) < 0.25 * len(points)


def test_opposite_normals_that_cancel_leave_no_mean_normal():
    # Two neighbours at the same distance with opposite normals: the weighted mean of
    # the normals is zero and stays zero (not 0 / 0).
    model = model_from_arrays(np.array([[-0.1, 0.0], [0.1, 0.0]]),
                              np.array([[0.0, 1.0], [0.0, -1.0]]))
    sample = implicit_surface(model, np.array([[0.0, 0.05]]), H, RADIUS, 4, 2)
    assert sample.defined[0]
    np.testing.assert_array_equal(sample.mean_normal, [[0.0, 0.0]])
    # A reference of one point still has a surface near it.
    single = model_from_arrays(np.array([[0.0, 0.0]]), np.array([[0.0, 1.0]]))
    sample = implicit_surface(single, np.array([[0.1, 0.05]]), H, RADIUS, 4, 1)
    assert sample.defined[0] and sample.value[0] == pytest.approx(0.05, abs=1e-12)


def test_gauss_newton_step_leaves_an_unconstrained_direction_alone():
    # Residuals from one wall (normal +y) constrain y only; x and theta stay put.
    jac = np.column_stack((np.zeros(10), np.ones(10), np.zeros(10)))
    step = gauss_newton_step(jac, np.full(10, 0.1), np.ones(10))
    np.testing.assert_allclose(step, [0.0, -0.1, 0.0], atol=1e-12)


def test_point_to_plane_jacobians_match_finite_differences():
    rng = np.random.default_rng(4)
    points = rng.uniform(-5, 5, (30, 2))
    angles = rng.uniform(-math.pi, math.pi, 30)
    normals = np.column_stack((np.cos(angles), np.sin(angles)))
    targets = rng.uniform(-5, 5, (30, 2))
    pose = se2.pose(0.3, -0.7, 0.4)
    residuals, jacobians = point_to_plane_system(pose, points, normals, targets)
    moved = se2.transform_points(pose, points)
    np.testing.assert_allclose(residuals, np.einsum('nd,nd->n', moved - targets, normals))
    eps = 1e-6
    for k in range(3):
        delta = np.zeros(3)
        delta[k] = eps
        plus, _ = point_to_plane_system(pose + delta, points, normals, targets)
        minus, _ = point_to_plane_system(pose - delta, points, normals, targets)
        np.testing.assert_allclose(jacobians[:, k], (plus - minus) / (2 * eps), atol=1e-7)


def test_weighted_step_solves_the_weighted_least_squares_and_drops_only_null_directions():
    # -(J^T W J)^-1 J^T W r for a full-rank system with uneven weights; a direction
    # 1e-10 times weaker than the strongest is left alone (the EIGEN_FLOOR of 1e-9),
    # one 1e-8 times weaker is solved, however small the strongest.
    rng = np.random.default_rng(2)
    jac, residuals = rng.normal(size=(30, 3)), rng.normal(size=30)
    weights = rng.uniform(0.1, 3.0, 30)
    root = np.sqrt(weights)[:, None]
    expected = np.linalg.lstsq(root * jac, -root[:, 0] * residuals, rcond=None)[0]
    np.testing.assert_allclose(gauss_newton_step(jac, residuals, weights), expected,
                               rtol=1e-10, atol=1e-12)
    # H = V diag(values) V^T with the weakest eigenvalue 1e-10 or 1e-8 of the strongest.
    q = np.linalg.qr(rng.normal(size=(30, 3)))[0]
    v = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    for strongest, weak, solved in ((1e6, 1e-10, False), (1e6, 1e-8, True),
                                    (1e-3, 1e-8, True)):
        values = strongest * np.array([1.0, 1e-6, weak])
        jac = q @ np.diag(np.sqrt(values)) @ v.T
        inverse = np.where([True, True, solved], 1.0 / values, 0.0)
        expected = -v @ (inverse * (v.T @ (jac.T @ residuals)))
        np.testing.assert_allclose(gauss_newton_step(jac, residuals, np.ones(30)), expected,
                                   rtol=1e-6, atol=1e-9)


def test_step_cosine_measures_rotation_as_the_arc_at_five_metres():
    # A turn of 0.02 rad counts as 0.1 m; a zero previous step has no direction.
    assert step_cosine(np.array([0.1, 0.0, 0.02]), np.array([0.0, 0.0, 0.02])) == \
        pytest.approx(math.sqrt(0.5), rel=1e-12)
    assert step_cosine(np.array([0.3, -0.4, 0.0]), np.array([-0.6, 0.8, 0.0])) == \
        pytest.approx(-1.0, rel=1e-12)
    assert step_cosine(np.array([0.1, 0.2, 0.0]), np.zeros(3)) == 0.0
    assert step_cosine(np.array([0.0, 0.1, 0.0]), np.array([0.1, 0.1, 0.0])) == \
        pytest.approx(math.sqrt(0.5), rel=1e-12)
    assert step_cosine(np.array([0.0, 0.0, 0.02]), np.array([0.1, 0.0, 0.02])) == \
        pytest.approx(math.sqrt(0.5), rel=1e-12)


def test_surface_information_reports_the_rms_of_the_inlier_distances():
    rng = np.random.default_rng(4)
    values = rng.normal(0.0, 0.01, 50)
    values[:3] = 1.0                                   # outliers, trimmed
    moved = rng.uniform(-5.0, 5.0, (50, 2))
    usable = np.ones(50, dtype=bool)
    normals = np.column_stack((np.cos(moved[:, 0]), np.sin(moved[:, 0])))
    translation = np.array([0.7, -0.4])
    information, rms = surface_information(moved, translation, values, normals, np.zeros(50),
                                           usable, 0.6, 3.0, kernel_code('none'), 0.05)
    assert rms == pytest.approx(math.sqrt(np.mean(values[3:] ** 2)), rel=1e-12)
    # Point to line, lever arms from the estimate's translation: J = [n, l x n].
    levers = moved[3:] - translation
    jac = np.column_stack((normals[3:], levers[:, 0] * normals[3:, 1]
                           - levers[:, 1] * normals[3:, 0]))
    variance = np.sum(values[3:] ** 2) / (47 - 3)
    np.testing.assert_allclose(information, jac.T @ jac / variance, rtol=1e-10)


def _refine_by_definition(cfg: ImlsConfig, model, chosen, first, estimate, far, capture):
    """Return the two stages of ``refine`` as its docstring states them (plain Python).

    The approach: unit weights, the capture radius when far, a step aligned with the
    last (cosine over ALIGNED_COSINE) doubled up to MAX_GAIN, until a step is under
    ``coarse_tolerance`` or COARSE_SHARE of the iterations have run. Then the inliers
    are fixed once and the robust kernel weighs the residuals; a step that reverses
    (negative cosine) halves the gain. Planarity weights throughout.
    """
    approach, gated, converged, iterations = True, False, False, 0
    previous, gain, sample = np.zeros(3), 1.0, first
    while iterations < cfg.max_iterations:
        iterations += 1
        if iterations > 1 or not far:
            radius = capture if approach and far else cfg.radius
            sample = implicit_surface(model, se2.transform_points(estimate, chosen), cfg.h,
                                      radius, cfg.max_neighbours, cfg.min_neighbours)
        if not approach and not gated:
            inlier = np.zeros(len(chosen), dtype=bool)
            inlier[sample.defined] = inlier_mask(sample.value[sample.defined],
                                                 cfg.min_keep_fraction, cfg.outlier_sigmas)
            chosen = chosen[inlier]
            sample = SurfaceSample(*(np.asarray(field)[inlier] for field in (
                sample.value, sample.normal, sample.defined, sample.count,
                sample.mean_normal, sample.nearest)))
            gated, previous, gain = True, np.zeros(3), 1.0
        ok = sample.defined
        if np.count_nonzero(ok) < cfg.min_correspondences:
            break
        along = (sample.normal if cfg.projection_normal == 'nearest' else sample.mean_normal)[ok]
        targets = project_onto_surface(se2.transform_points(estimate, chosen[ok]),
                                       sample.value[ok], along)
        residuals, jacobians = point_to_plane_system(estimate, chosen[ok], along, targets)
        weights = (np.ones(len(residuals)) if approach else kernel_weights(
            residuals, kernel_code(cfg.robust_kernel), cfg.robust_scale))
        weights = weights * planarity(model.curvature[sample.nearest[ok]]) ** cfg.planarity_power
        step = gauss_newton_step(jacobians, residuals, weights)
        cosine = step_cosine(step, previous)
        if approach:
            gain = min(2.0 * gain, MAX_GAIN) if cosine > ALIGNED_COSINE else 1.0
        elif cosine < 0.0:
            gain *= 0.5
        previous = step
        estimate = advance(estimate, gain * step)
        if approach:
            approach = (not se2.is_small_step(step, cfg.coarse_tolerance, cfg.coarse_tolerance)
                        and iterations < COARSE_SHARE * cfg.max_iterations)
        elif se2.is_small_step(gain * step, cfg.convergence_translation,
                               cfg.convergence_rotation):
            converged = True
            break
    return estimate, converged, iterations


@pytest.mark.parametrize('world, settings, guess, noise', [
    (ROOM, {}, se2.pose(0.05, -0.03, 0.02), 0.01),                    # near: fine radius
    (ROOM, {}, se2.pose(0.25, 0.2, -0.1), 0.01),                      # far: capture radius
    (ROOM, {'planarity_power': 0.5, 'projection_normal': 'mean'}, se2.pose(0.05, 0.0, 0.03),
     0.01),
    (ROOM, {'planarity_power': 0.0, 'robust_kernel': 'cauchy', 'robust_scale': 0.01},
     se2.pose(0.1, 0.1, 0.0), 0.01),
    (ROOM, {'robust_kernel': 'tukey', 'robust_scale': 0.01}, se2.pose(0.05, -0.03, 0.02),
     0.02),                                                            # long aligned runs
    (ROOM, {'max_neighbours': 1, 'min_neighbours': 1}, se2.pose(0.05, 0.0, 0.02), 0.01),
    (CORRIDOR, {}, se2.pose(0.4, 0.05, 0.0), 0.01),                   # steps that reverse
    (CORRIDOR, {'coarse_tolerance': 0.0}, se2.pose(0.4, 0.05, 0.0), 0.01),  # creeping
    (ROOM, {'max_iterations': 6, 'coarse_tolerance': 0.0}, se2.pose(0.3, 0.0, 0.1),
     0.01),                                                            # the share and cap
    (ROOM, {'min_correspondences': 301}, se2.pose(0.05, 0.0, 0.0), 0.01),   # too few
])
def test_refinement_follows_its_two_stages(world, settings, guess, noise):
    truth = se2.pose(0.2, 0.1, 0.05) if world is ROOM else se2.pose()
    laser = LaserModel(beams=720, fov=2.0 * math.pi, max_range=20.0, noise_sigma=noise)
    reference = _scan(world, se2.pose(0.0, 0.0, 0.0), laser, seed=3)
    current = _scan(world, truth, laser, seed=4)
    matcher = create_matcher('imls', settings)
    cfg = matcher.config
    model = matcher._model(reference)
    chosen = current.points[::2][:300]
    estimate = se2.compose(truth, guess)
    capture = max(cfg.radius, cfg.max_correspondence_distance)
    first = implicit_surface(model, se2.transform_points(estimate, chosen), cfg.h, capture,
                             cfg.max_neighbours, cfg.min_neighbours)
    far = bool(np.median(np.abs(first.value)) > COARSE_FRACTION * cfg.radius)
    compiled = matcher._refine(model, chosen, first, estimate, capture)
    spec = _refine_by_definition(cfg, model, chosen, first, estimate, far, capture)
    np.testing.assert_allclose(compiled[0], spec[0], rtol=0, atol=1e-12)
    assert compiled[1:] == spec[1:]


def test_inverted_information_is_the_covariance_of_the_inverse():
    # Carrying H of U to T = U^-1 must agree with propagating U's covariance through
    # the Jacobian of the inverse: Sigma_T = J Sigma_U J^T.
    backward = se2.pose(0.4, -0.3, 0.7)
    root = np.array([[2.0, 0.3, 0.1], [0.0, 1.5, -0.2], [0.0, 0.0, 0.8]])
    information = root.T @ root * 100.0
    jacobian = se2.inverse_jacobian(backward)
    expected = jacobian @ np.linalg.inv(information) @ jacobian.T
    carried = inverted_information(backward, information)
    np.testing.assert_allclose(np.linalg.inv(carried), expected, rtol=1e-9, atol=1e-12)


def test_fusion_weighs_the_two_directions_by_their_information():
    forward = se2.pose(0.10, 0.00, 0.020)
    other = se2.pose(0.12, 0.02, 0.030)                   # the backward estimate of T
    backward = se2.inverse(other)
    information = np.diag([1e4, 1e4, 1e5])
    jacobian = se2.inverse_jacobian(backward)
    # Same information about T from both sides: the midpoint.
    same = jacobian.T @ information @ jacobian
    fused, difference = fuse_directions(forward, information, backward, same)
    np.testing.assert_allclose(fused, 0.5 * (forward + other), atol=1e-9)
    np.testing.assert_allclose(difference, other - forward, atol=1e-12)
    # Three times the information: three quarters of the way.
    fused, _ = fuse_directions(forward, information, backward, 3.0 * same)
    np.testing.assert_allclose(fused, forward + 0.75 * (other - forward), atol=1e-9)
    # No information about x on the backward side: x stays with the forward estimate.
    blind = jacobian.T @ np.diag([0.0, 1e4, 1e5]) @ jacobian
    fused, _ = fuse_directions(forward, information, backward, blind)
    assert abs(fused[0] - forward[0]) < 1e-9
    np.testing.assert_allclose(fused[1:], 0.5 * (forward[1:] + other[1:]), atol=1e-9)


def test_symmetric_match_averages_out_a_sparse_noisy_reference():
    # A 1-degree reference with 2 cm noise against a dense exact current scan: the
    # forward match inherits the reference's noise, the backward one does not.
    office = get_world('office')
    sparse = LaserModel(beams=180, fov=2.0 * math.pi, max_range=20.0, noise_sigma=0.02)
    dense = LaserModel(beams=1080, fov=2.0 * math.pi, max_range=20.0, noise_sigma=0.0)
    symmetric = create_matcher('imls')
    forward_only = create_matcher('imls', {'symmetric': False})
    rng = np.random.default_rng(1)
    start = se2.pose(10.0, -5.0, 1.0)
    errors = []
    for k in range(20):
        truth = se2.pose(rng.uniform(0.0, 0.2), rng.uniform(-0.05, 0.05),
                         rng.uniform(-0.1, 0.1))
        reference = _scan(office, start, sparse, seed=2 * k)
        current = _scan(office, se2.compose(start, truth), dense, seed=2 * k + 1)
        guess = truth + np.array([0.01, 0.01, 0.005])
        both = symmetric.match(reference, current, guess)
        assert both.extra['symmetric']
        one = forward_only.match(reference, current, guess)
        errors.append([abs(se2.relative(truth, r.pose)[2]) for r in (one, both)])
    one_way, two_way = np.degrees(np.mean(errors, axis=0))
    assert two_way < 0.75 * one_way          # measured 0.032 against 0.057 deg


def test_a_backward_match_that_lost_the_surface_is_not_fused():
    matcher = create_matcher('imls')
    forward = MatchResult(se2.pose(0.1, 0.0, 0.02), True, 4, 0.9, 0.01, np.eye(3) * 1e4,
                          np.eye(3) * 1e-4, 100, extra={'selected': 100})
    far = replace(forward, pose=se2.inverse(se2.pose(0.6, 0.0, 0.02)))
    kept = matcher._symmetric(forward, far)
    np.testing.assert_array_equal(kept.pose, forward.pose)
    assert kept.extra == {'selected': 100, 'symmetric': False}
    failed = replace(forward, pose=se2.inverse(se2.pose(0.12, 0.0, 0.02)), converged=False)
    assert not matcher._symmetric(forward, failed).extra['symmetric']
    near = replace(forward, pose=se2.inverse(se2.pose(0.12, 0.0, 0.02)))
    fused = matcher._symmetric(forward, near)
    assert fused.extra['symmetric'] and fused.iterations == 8
    assert fused.pose[0] == pytest.approx(0.11, abs=1e-3)


@pytest.mark.parametrize('truth, guess', [
    (se2.pose(0.12, -0.05, 0.04), se2.pose()),
    (se2.pose(-0.25, 0.15, -0.12), se2.pose(-0.1, 0.1, -0.05)),
    (se2.pose(0.3, 0.2, 0.2), se2.pose(0.2, 0.1, 0.1)),
])
def test_exact_recovery_on_noise_free_scans(truth, guess):
    start = se2.pose(0.3, -0.2, 0.3)
    reference = _scan(ROOM, start)
    current = _scan(ROOM, se2.compose(start, truth))
    result = create_matcher('imls').match(reference, current, guess)
    assert result.converged
    error = se2.relative(truth, result.pose)
    assert math.hypot(error[0], error[1]) < 2e-3
    assert abs(error[2]) < math.radians(0.05)
    # Only the corners, which the IMLS surface rounds off, leave residuals.
    assert result.residual < 1e-2
    assert result.inlier_ratio > 0.9


def test_information_covers_all_points_and_reveals_a_corridor():
    # Same scan twice inside a long featureless stretch: x is (nearly) unobservable.
    long_corridor = World('imls-long', 'parallel walls',
                          geo.stack(geo.wall((-60.0, -1.0), (60.0, -1.0)),
                                    geo.wall((-60.0, 1.0), (60.0, 1.0))), np.zeros((2, 2)))
    laser = LaserModel(beams=360, fov=2 * math.pi, max_range=8.0, noise_sigma=0.005)
    reference = _scan(long_corridor, se2.pose(), laser, seed=1)
    current = _scan(long_corridor, se2.pose(0.1, 0.0, 0.0), laser, seed=2)
    matcher = create_matcher('imls', {'points_per_list': 30})
    result = matcher.match(reference, current, se2.pose(0.1, 0.0, 0.0))
    assert result.converged
    assert result.correspondences > 0.8 * len(current)         # all points, not the selection
    assert result.correspondences > 2 * result.extra['selected']
    values, vectors = np.linalg.eigh(result.information)
    assert abs(vectors[0, 0]) > 0.99                              # weakest direction: x
    assert values[0] < 1e-3 * values[1]
    np.testing.assert_allclose(result.covariance @ result.information, np.eye(3), atol=1e-6)
    assert abs(result.pose[1]) < 5e-3 and abs(result.pose[2]) < 2e-3


def test_registered_with_validated_parameters():
    assert 'imls' in matcher_names()
    assert isinstance(create_matcher('imls'), ImlsMatcher)
    config = default_config('imls')
    assert isinstance(config, ImlsConfig)
    assert create_matcher('imls', {'h': 0.05, 'points_per_list': 30}).config.h == 0.05
    with pytest.raises(ParameterError):
        create_matcher('imls', {'h': -1.0})
    with pytest.raises(ParameterError):
        create_matcher('imls', {'robust_kernel': 'bogus'})


def test_yaml_restates_the_tuned_defaults():
    document = yaml.safe_load(CONFIG_FILE.read_text())
    params = document['/**']['ros__parameters']
    assert params['matcher'] == 'imls'
    assert params['imls'] == as_dict(ImlsConfig())
    flat = {'matcher': 'imls', **{f'imls.{k}': v for k, v in params['imls'].items()}}
    config = pipeline_config_from_params(flat)
    assert config.matcher == 'imls' and config.matcher_config == ImlsConfig()


def test_pipeline_tracks_a_noisy_drive_through_the_room():
    laser = LaserModel(beams=360, fov=2 * math.pi, max_range=20.0, noise_sigma=0.01)
    pipeline = OdometryPipeline(PipelineConfig(matcher='imls'))
    rng = np.random.default_rng(5)
    truth = [se2.pose(-1.0, -1.0, 0.0)]
    for _ in range(40):
        truth.append(se2.compose(truth[-1], se2.pose(0.08, 0.0, 0.03)))
    estimate = None
    for i, pose in enumerate(truth):
        scan = render_scan(ROOM, pose, laser, rng, stamp_ns=(i + 1) * 100_000_000)
        estimate = pipeline.process(scan)
        assert estimate.status in ('initialized', 'matched')
    expected = se2.relative(truth[0], truth[-1])
    error = se2.relative(expected, estimate.pose)
    assert math.hypot(error[0], error[1]) < 0.03
    assert abs(error[2]) < math.radians(0.5)


def test_heading_search_recovers_a_missed_turn():
    # A guess 0.3 rad off in heading (the robot started turning): the iterations alone
    # settle in a wrong minimum, the heading search re-seeds them.
    office = get_world('office')
    start = se2.pose(10.0, -5.0, 1.0)
    truth = se2.pose(0.1, 0.0, 0.3)
    reference = _scan(office, start)
    current = _scan(office, se2.compose(start, truth))
    guess = se2.pose(0.1, 0.0, 0.0)
    result = create_matcher('imls').match(reference, current, guess)
    error = se2.relative(truth, result.pose)
    assert result.converged
    assert math.hypot(error[0], error[1]) < 2e-3 and abs(error[2]) < 1e-3
    blind = create_matcher('imls', {'search_angle': 0.0}).match(reference, current, guess)
    assert math.hypot(*se2.relative(truth, blind.pose)[:2]) > 0.1


def test_clutter_in_the_current_scan_is_ignored():
    # Three "legs" in front of the robot that the reference scan did not see.
    laser = LaserModel(beams=360, fov=2 * math.pi, max_range=20.0, noise_sigma=0.01)
    crowded = World('imls-crowded', 'the room with people in it',
                    geo.stack(ROOM.segments, geo.pillar(0.9, -0.4, 0.12),
                              geo.pillar(1.2, -0.1, 0.12), geo.pillar(-0.5, 0.8, 0.15)),
                    np.zeros((2, 2)))
    start = se2.pose(0.3, -0.2, 0.3)
    truth = se2.pose(0.15, 0.0, 0.05)
    reference = _scan(ROOM, start, laser, seed=1)
    current = _scan(crowded, se2.compose(start, truth), laser, seed=2)
    result = create_matcher('imls').match(reference, current, se2.pose(0.1, 0.0, 0.0))
    error = se2.relative(truth, result.pose)
    assert result.converged
    assert math.hypot(error[0], error[1]) < 3e-3 and abs(error[2]) < math.radians(0.1)


def test_real_log_mit_csail_first_500_scans(shared_data_dir):
    dataset = load_dataset(shared_data_dir / 'mit-csail' / 'mit-csail.clf')
    result = run_pipeline(OdometryPipeline(PipelineConfig(matcher='imls')),
                          dataset.scans[:500])
    errors = evaluate(result.trajectory, dataset.reference)
    assert errors.steps >= 130
    assert errors.rpe_trans_mean < 0.03        # measured 0.021 m
    assert errors.rpe_rot_mean < 0.45          # measured 0.34 deg
    assert errors.ate_rms < 0.4                # measured 0.14 m
    assert errors.failed_steps == 0
    assert result.counters['rejected'] == 0


def test_noise_of_the_normals_does_not_pose_as_information_along_a_corridor():
    """Walls along x whose normals scatter by s: plain point to line sees the axis."""
    rng = np.random.default_rng(7)
    count, s = 400, 0.05
    x = rng.uniform(-10.0, 10.0, count)
    y = np.where(np.arange(count) % 2 == 0, 1.5, -1.5)
    points = np.column_stack((x, y))
    angle = np.pi / 2 + rng.normal(0.0, s, count)
    normals = np.column_stack((np.cos(angle), np.sin(angle)))
    residuals = rng.normal(0.0, 0.01, count)
    weights = np.ones(count)
    plain = point_to_line_information(points, normals, residuals, weights)
    debiased = debiased_point_to_line_information(points, normals, residuals, weights,
                                                  np.full(count, s * s))
    across = plain[1, 1]
    # Plain: the axis looks observed by count s^2 of the across weight.
    assert plain[0, 0] == pytest.approx(count * s * s / np.var(residuals), rel=0.25)
    assert plain[0, 0] > 1e-3 * across
    # Debiased: what the normals' noise put there is gone (the sum stays PSD).
    assert debiased[0, 0] < 0.1 * plain[0, 0]
    assert np.all(np.linalg.eigvalsh(debiased) >= -1e-9 * across)
    assert debiased[1, 1] == pytest.approx(across, rel=0.01)
    # Without normal noise the two are the same.
    np.testing.assert_allclose(
        debiased_point_to_line_information(points, normals, residuals, weights,
                                           np.zeros(count)), plain, rtol=1e-9, atol=1e-9)
