"""The correlative global search: exact branch and bound, admissible bounds, ambiguity."""

import math

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.core.scan.laser_scan import scan_to_points, ScanPoints
from laser_odom.core.search import correlative_search, SearchWindow
from laser_odom.core.search.correlative import search_tree
from laser_odom.core.search.grid import LIKELIHOOD_STEPS, LikelihoodGrid
from laser_odom.core.search.tree import coarsen
from laser_odom.core.simulation import geometry as geo, get_world, LaserModel, render_scan
from laser_odom.core.simulation.world import World

LARGE_MOTION = se2.pose(0.8, 0.0, math.radians(25.0))


def office_pair(t: float, motion: np.ndarray, seed: int = 0):
    """Return reference and current points of the office, ``motion`` apart, 1 cm noise."""
    world = get_world('office')
    start = world.path.poses_at(np.array([t]))[0]
    rng = np.random.default_rng(seed)
    laser = LaserModel()
    reference = scan_to_points(render_scan(world, start, laser, rng))
    current = scan_to_points(render_scan(world, se2.compose(start, motion), laser, rng))
    return reference, current


def square_room() -> World:
    """Return a 5 x 5 m empty room: a quarter turn about its centre changes nothing."""
    walls = geo.rectangle(-2.5, -2.5, 2.5, 2.5)
    return World('square', 'empty square room', walls, np.array([[0.0, 0.0]]))


def test_coarsen_only_rounds_up_to_few_values():
    values = np.arange(0, 200)
    rounded = coarsen(values)
    assert np.all(rounded >= values)
    assert np.all(rounded[:9] == values[:9])
    assert list(np.unique(rounded[8:15])) == [8, 10, 12, 14]
    assert np.all(rounded <= 1.25 * np.maximum(values, 1) + 1)


def test_bound_grids_hold_the_maximum_of_their_window():
    rng = np.random.default_rng(3)
    surface = rng.uniform(-2.0, 2.0, (200, 2))
    grid = LikelihoodGrid(surface, 0.1, 0.1, np.array([-25, -25]), (50, 50), [1, 3, 6, 13])
    fine = grid.fine.reshape(grid.shape)
    assert fine.max() == LIKELIHOOD_STEPS
    for window in (3, 6, 13):
        table = grid.tables[grid.table_start(window):][:grid.cells].reshape(grid.shape)
        for i, j in rng.integers(0, 50, (40, 2)):
            assert table[i, j] == fine[i:i + window, j:j + window].max()


def test_the_fine_table_is_the_kernel_of_the_nearest_surface_cell():
    """Each cell holds the largest 255 exp(-d^2 / 2 sigma^2) over the surface's cells."""
    rng = np.random.default_rng(5)
    surface = rng.uniform(-1.5, 1.5, (60, 2))
    resolution, sigma = 0.1, 0.12
    grid = LikelihoodGrid(surface, resolution, sigma, np.array([-20, -20]), (40, 40), [1, 4])
    fine = grid.fine.reshape(grid.shape)[:40, :40]
    marked = np.unique(np.rint(surface / resolution).astype(int), axis=0)
    cells = np.stack(np.meshgrid(np.arange(-20, 20), np.arange(-20, 20), indexing='ij'),
                     axis=-1).reshape(-1, 2)
    squared = np.sum(np.square(cells[:, None, :] - marked[None, :, :]), axis=2) * resolution ** 2
    weights = np.rint(LIKELIHOOD_STEPS * np.exp(-0.5 * squared / sigma ** 2))
    reach = math.ceil(3.0 * sigma / resolution)  # the kernel's extent (KERNEL_SIGMAS)
    near = np.max(np.abs(cells[:, None, :] - marked[None, :, :]), axis=2) <= reach
    expected = np.max(np.where(near, weights, 0), axis=1).reshape(40, 40)
    np.testing.assert_array_equal(fine, expected)


def test_a_leaf_scores_the_fine_table_where_its_pose_puts_each_point():
    """A leaf's exact score sums the fine table at every point's cell, rounded."""
    reference, current = office_pair(20.0, se2.pose(0.1, 0.05, math.radians(5.0)))
    tree = search_tree(reference, current, se2.pose(0.05, 0.0, 0.02),
                       SearchWindow(linear=0.3, angular=math.radians(10.0)))
    grid = tree.grid
    fine = grid.fine.reshape(grid.shape)
    leaves = tree.leaves()[np.random.default_rng(2).choice(len(tree.leaves()), 50)]
    expected = []
    for j, i, k in leaves:
        angle = tree.theta0 + j * tree.angle_step
        rotated = se2.transform_points(se2.pose(0.0, 0.0, angle), tree.points)
        cells = np.rint(rotated / grid.resolution).astype(int) + tree.translation_low + (i, k)
        expected.append(int(fine[cells[:, 0] - grid.low[0], cells[:, 1] - grid.low[1]].sum()))
    np.testing.assert_array_equal(tree.scores(0, leaves), expected)


def test_branch_and_bound_finds_every_near_best_leaf_of_the_exhaustive_search():
    reference, current = office_pair(12.0, se2.pose(0.2, -0.1, math.radians(8.0)))
    window = SearchWindow(linear=0.4, angular=math.radians(12.0))
    guess = se2.pose()
    tree = search_tree(reference, current, guess, window)
    leaves = tree.leaves()
    exact = tree.scores(0, leaves)
    result = correlative_search(reference, current, guess, window, keep_ratio=0.9)
    assert result.exhaustive
    best = exact.max() / (LIKELIHOOD_STEPS * result.points)
    assert result.best.score == pytest.approx(best)
    near = tree.poses(leaves[exact >= 0.9 * exact.max()])
    # The reported peaks are all among the near-best leaves, the best one first.
    for peak in result.peaks:
        assert np.min(np.abs(near - peak.pose).sum(axis=1)) < 1e-9


def sparse_pair(motion: np.ndarray) -> tuple[ScanPoints, ScanPoints]:
    """Return isolated reference points 4-20 m away and the same seen after ``motion``.

    Nothing blurs a lone point: a node's bound is tight only if every rotation in the
    node is accounted for, which makes the bounds' rotational reach testable.
    """
    rng = np.random.default_rng(11)
    radius, angle = rng.uniform(4.0, 20.0, 24), rng.uniform(-math.pi, math.pi, 24)
    points = np.column_stack((radius * np.cos(angle), radius * np.sin(angle)))
    seen = se2.transform_points(se2.inverse(motion), points)
    beams = np.arange(0, 240, 10)  # not neighbours: no surface between them
    return (ScanPoints(points, beams, np.hypot(*points.T)),
            ScanPoints(seen, beams, np.hypot(*seen.T)))


@pytest.mark.parametrize('scene', ['office', 'sparse'])
def test_every_node_bound_covers_all_its_leaves(scene):
    if scene == 'office':
        reference, current = office_pair(30.0, LARGE_MOTION, seed=1)
    else:
        reference, current = sparse_pair(LARGE_MOTION)
    guess = se2.compose(LARGE_MOTION, se2.pose(0.1, -0.1, math.radians(10.0)))
    tree = search_tree(reference, current, guess,
                       SearchWindow(linear=0.4, angular=math.radians(30.0)))
    leaves = tree.leaves()
    exact = tree.scores(0, leaves)
    assert tree.depth >= 3
    for level in range(1, tree.depth + 1):
        block = 2 ** level
        keys, owner = np.unique(leaves // block * block, axis=0, return_inverse=True)
        leaf_max = np.zeros(len(keys), dtype=np.int64)
        np.maximum.at(leaf_max, owner.ravel(), exact)
        bounds = tree.scores(level, keys)
        assert np.all(bounds >= leaf_max), f'level {level}'
        if level <= 2:  # ... and low levels prune: bounds are not all the full score
            assert bounds.min() < 0.9 * LIKELIHOOD_STEPS * len(tree.points)


@pytest.mark.parametrize('t', [5.0, 20.0, 40.0])
def test_large_motion_is_found_without_a_guess(t):
    reference, current = office_pair(t, LARGE_MOTION)
    result = correlative_search(reference, current, se2.pose(), SearchWindow())
    error = se2.relative(LARGE_MOTION, result.best.pose)
    assert np.hypot(error[0], error[1]) < 0.1
    assert abs(error[2]) < math.radians(1.0)
    assert result.exhaustive and result.ambiguity < 0.9


def test_square_room_is_ambiguous_by_a_quarter_turn():
    room = square_room()
    laser = LaserModel()
    rng = np.random.default_rng(4)
    reference = scan_to_points(render_scan(room, se2.pose(), laser, rng))
    turned = se2.pose(0.0, 0.0, math.radians(30.0))
    current = scan_to_points(render_scan(room, turned, laser, rng))
    result = correlative_search(reference, current, se2.pose(), SearchWindow())
    assert result.ambiguity > 0.97
    headings = sorted(math.degrees(p.pose[2]) for p in result.peaks[:2])
    assert headings == pytest.approx([-60.0, 30.0], abs=1.5)


def test_too_few_points_give_no_result():
    reference, current = office_pair(5.0, se2.pose())
    few = scan_to_points(render_scan(get_world('office'), se2.pose(), LaserModel(beams=8)))
    assert correlative_search(reference, few, se2.pose(), SearchWindow()) is None
