"""The bearing index finds exactly the nearest point a KD-tree finds, within the gate."""

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from laser_odom.core.scan.nearest import BearingIndex


def kd_nearest(points: np.ndarray, queries: np.ndarray, gate: float):
    """Return the KD-tree's answer, as ``BearingIndex.nearest`` gives it."""
    if len(points) == 0:
        return np.full(len(queries), np.inf), np.zeros(len(queries), dtype=int)
    return cKDTree(points).query(queries, k=1, distance_upper_bound=gate)


@pytest.mark.parametrize('seed', range(40))
def test_random_clouds_agree_with_a_kd_tree(seed):
    rng = np.random.default_rng(seed)
    points = rng.normal(0.0, rng.choice([0.2, 3.0]), (int(rng.integers(0, 80)), 2))
    queries = rng.normal(0.0, 3.0, (60, 2))
    gate = float(rng.choice([0.05, 0.3, 2.0, 50.0]))
    distance, index = BearingIndex(points).nearest(queries, gate)
    want_distance, want_index = kd_nearest(points, queries, gate)
    assert np.array_equal(index, want_index)
    assert np.allclose(distance, want_distance)


def test_a_scan_ring_across_the_back_agrees_and_finds_its_own_points():
    """A 360 deg scan: bearings wrap at +-pi, and every point is its own nearest."""
    angles = np.linspace(-math.pi, math.pi, 720, endpoint=False)
    ranges = 3.0 + np.sin(5 * angles)
    points = np.column_stack((ranges * np.cos(angles), ranges * np.sin(angles)))
    index = BearingIndex(points)
    distance, nearest = index.nearest(points, 0.01)
    assert np.array_equal(nearest, np.arange(720)) and np.all(distance == 0.0)
    rng = np.random.default_rng(3)
    queries = points + rng.normal(0.0, 0.1, points.shape)
    got = index.nearest(queries, 0.25)
    want = kd_nearest(points, queries, 0.25)
    assert np.array_equal(got[1], want[1]) and np.allclose(got[0], want[0])


def test_a_query_that_starts_from_its_predecessors_answer_still_breaks_ties_by_index():
    # A query without a hint starts from the previous query's nearest point. The second
    # query lies as near to point 0 as to point 1 and starts from point 1 (the first
    # query's answer): ties go to the lower index whatever the start.
    points = np.array([[1.0, 1.0], [1.0, -1.0], [4.0, 0.0]])
    queries = np.array([[1.0, -0.9], [1.0, 0.0], [1.0, 0.0]])
    distance, index = BearingIndex(points).nearest(queries, 2.0)
    assert index.tolist() == [1, 0, 0] and distance[1] == distance[2] == 1.0


def test_queries_at_the_origin_and_points_at_the_origin():
    points = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, -0.5]])
    queries = np.array([[0.0, 0.0], [0.1, 0.0], [-0.2, -0.2], [5.0, 5.0]])
    distance, index = BearingIndex(points).nearest(queries, 1.0)
    assert index.tolist() == [0, 0, 0, 3]  # the last: nothing within 1 m -> n
    assert distance[3] == np.inf and distance[0] == 0.0


@pytest.mark.parametrize('seed', range(30))
def test_k_nearest_agrees_with_a_kd_tree(seed):
    rng = np.random.default_rng(100 + seed)
    points = rng.normal(0.0, 2.0, (int(rng.integers(1, 60)), 2))
    queries = np.vstack((points[:10], rng.normal(0.0, 2.0, (30, 2))))
    k, gate = int(rng.integers(1, 25)), float(rng.choice([0.3, 1.0, np.inf]))
    distance, index = BearingIndex(points).k_nearest(queries, k, gate)
    tree = cKDTree(points)
    k_eff = min(k, len(points))
    want_distance, want_index = tree.query(queries, k=k_eff, distance_upper_bound=gate)
    want_distance = np.asarray(want_distance).reshape(len(queries), k_eff)
    want_index = np.asarray(want_index).reshape(len(queries), k_eff)
    assert np.allclose(distance[:, :k_eff], want_distance)
    want_index = np.where(np.isfinite(want_distance), want_index, len(points))
    assert np.array_equal(index[:, :k_eff], want_index)
    assert np.all(np.isinf(distance[:, k_eff:])) and np.all(index[:, k_eff:] == len(points))
