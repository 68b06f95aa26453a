"""The local map: its hash of cells, its bounds, the view it renders and what it forgets.

Scans here are ray-cast in small worlds of wall segments, so every test knows where
the surfaces are.
"""

import math

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import LocalMapConfig
from laser_odom.core.registration.local_map.cells import ALIVE, EMPTY, KEY
from laser_odom.core.registration.local_map.map import LocalMap, MapGeometry
from laser_odom.core.registration.local_map.reference import MapReference, MAX_REFUSED
from laser_odom.core.registration.local_map.view import render_view
from laser_odom.core.scan.laser_scan import LaserMounting, ScanPoints
from laser_odom.core.simulation.geometry import rectangle, stack, wall
from laser_odom.core.simulation.raycast import cast_rays

BEAMS = 720
BIN = 2.0 * math.pi / BEAMS
SENSOR = np.zeros(2)
ROOM = rectangle(-3.978, -2.978, 4.022, 3.022)
"""An 8 m x 6 m room, its walls inside cells (not along cell borders)."""


def geometry(**changes) -> MapGeometry:
    """Return the default map geometry with ``changes``."""
    values = {'resolution': 0.05, 'radius': 50.0, 'max_cells': 30000, 'max_weight': 20.0,
              'max_age': 50}
    values.update(changes)
    return MapGeometry(**values)


def scan_points(world: np.ndarray, pose, noise: float = 0.0, seed: int = 0) -> np.ndarray:
    """Return a 360 deg scan of ``world`` from base ``pose`` as base-frame points."""
    angles = np.arange(BEAMS) * BIN - math.pi
    ranges = cast_rays(np.asarray(pose[:2], dtype=float), angles + pose[2], world, 30.0)
    ranges = ranges + np.random.default_rng(seed).normal(0.0, noise, BEAMS) if noise else ranges
    keep = np.isfinite(ranges)
    return np.column_stack((ranges[keep] * np.cos(angles[keep]),
                            ranges[keep] * np.sin(angles[keep])))


def view_ranges(local_map: LocalMap, pose) -> tuple[np.ndarray, np.ndarray]:
    """Return the view's bearings and ranges from base ``pose``."""
    view = local_map.view(np.asarray(pose, dtype=float), SENSOR, BIN, 30.0)
    return np.arctan2(view.points[:, 1], view.points[:, 0]), view.ranges


def true_range(world: np.ndarray, pose, bearings: np.ndarray) -> np.ndarray:
    """Return the true range of ``world`` along base-frame ``bearings`` from ``pose``."""
    return cast_rays(np.asarray(pose[:2], dtype=float), bearings + pose[2], world, 30.0)


def test_points_of_one_cell_share_it_and_scans_again_add_no_cells():
    local_map = LocalMap(geometry())
    points = scan_points(ROOM, se2.pose())
    local_map.insert(points, se2.pose(), SENSOR, BIN)
    cells = len(local_map)
    # The room's 28 m of wall cross 28 / 0.05 cells (a few fewer where beams fall more
    # than a cell apart): fewer than the 720 points.
    assert 0.9 * 28.0 / 0.05 <= cells <= 28.0 / 0.05 + 4 and cells < len(points)
    for k in range(5):
        pose = se2.pose(0.01 * k, 0.0, 0.02 * k)
        local_map.insert(scan_points(ROOM, pose), pose, SENSOR, BIN)
    assert len(local_map) <= 28.0 / 0.05 + 4
    means, weights = local_map.cell_means()
    assert len(means) == len(local_map) and np.all(weights >= 1.0)


def test_the_hash_finds_every_cell_after_many_insertions_and_removals():
    # A robot driving 40 m down a corridor with a small map: cells come and go all the
    # time (radius, age, budget), which exercises the backward-shift deletion.
    doors = [(10.0, 11.0), (30.0, 31.0)]
    corridor = stack(wall((-5.0, -1.0), (60.0, -1.0)), wall((-5.0, 1.0), (60.0, 1.0), doors))
    local_map = LocalMap(geometry(radius=8.0, max_cells=700, max_age=20))
    for k in range(200):
        pose = se2.pose(0.2 * k, 0.05 * math.sin(0.1 * k), 0.02 * math.sin(0.3 * k))
        local_map.insert(scan_points(corridor, pose), pose, SENSOR, BIN)
        assert len(local_map) <= 700
    means, _ = local_map.cell_means()
    alive = np.flatnonzero(local_map._ints[:, ALIVE])
    assert [local_map.find(p) for p in means] == list(alive)
    stored = local_map._slot_keys != EMPTY
    assert np.count_nonzero(stored) == len(local_map)
    assert set(local_map._slot_keys[stored]) == set(local_map._ints[alive, KEY])
    # Bounded by the radius around the last pose: nothing of the corridor's start.
    assert np.max(np.hypot(*(means - pose[:2]).T)) <= 8.0 + 0.1


def test_the_loops_over_cells_see_every_cell_and_skip_rows_never_used():
    # The same churn with a roomy budget: cells come and go, rows are reused, and the
    # loops of the view, the carving and the staleness check stop at the rows ever in use.
    doors = [(10.0, 11.0), (30.0, 31.0)]
    corridor = stack(wall((-5.0, -1.0), (60.0, -1.0)), wall((-5.0, 1.0), (60.0, 1.0), doors))
    local_map = LocalMap(geometry(radius=8.0, max_cells=30000, max_age=20))
    most = 0
    for k in range(120):
        pose = se2.pose(0.2 * k, 0.05 * math.sin(0.1 * k), 0.02 * math.sin(0.3 * k))
        local_map.insert(scan_points(corridor, pose), pose, SENSOR, BIN)
        most = max(most, len(local_map))
        _, ints = local_map._used()
        assert len(ints) >= most and not local_map._ints[len(ints):].any()  # never touched
        assert local_map._ints[len(ints) - 1].any()  # and the last row visited was
        assert np.array_equal(np.flatnonzero(ints[:, ALIVE]),
                              np.flatnonzero(local_map._ints[:, ALIVE]))
    assert most < 3000 and len(local_map) < most
    whole = render_view(local_map._floats, local_map._ints, pose, SENSOR, BIN, 30.0, 0.1,
                        0.025, 1, local_map.insertions)
    assert np.array_equal(local_map.view(pose, SENSOR, BIN, 30.0).points, whole[:, :2])
    local_map.clear()
    assert len(local_map._used()[1]) == 0


def cells_within(local_map: LocalMap, centre, radius: float) -> int:
    """Return how many cells of the map have their mean within ``radius`` of ``centre``."""
    means, _ = local_map.cell_means()
    return int(np.count_nonzero(np.hypot(*(means - np.asarray(centre)).T) <= radius))


def test_cells_unseen_for_max_age_insertions_are_dropped():
    local_map = LocalMap(geometry(max_age=5))
    pillar = rectangle(1.0, 1.0, 1.2, 1.2)
    local_map.insert(scan_points(stack(ROOM, pillar), se2.pose()), se2.pose(), SENSOR, BIN)
    assert cells_within(local_map, (1.1, 1.1), 0.15) >= 6
    # Seen no more: later insertions bring a few points of one corner of the room, and
    # no beam of theirs crosses the pillar.
    corner = scan_points(ROOM, se2.pose(-3.5, -2.5, 0.0))
    corner = corner[np.hypot(*corner.T) < 0.6]
    for k in range(6):  # it survives max_age insertions, and goes at the next
        local_map.insert(corner, se2.pose(-3.5, -2.5, 0.0), SENSOR, BIN)
        assert cells_within(local_map, (1.1, 1.1), 0.15) >= (6 if k < 5 else 0)
    assert cells_within(local_map, (1.1, 1.1), 0.15) == 0
    assert cells_within(local_map, (-3.978, -2.978), 0.6) > 0


def test_the_view_averages_the_noise_of_many_scans():
    local_map = LocalMap(geometry())
    for seed in range(20):
        local_map.insert(scan_points(ROOM, se2.pose(), noise=0.01, seed=seed), se2.pose(),
                         SENSOR, BIN)
    pose = se2.pose(0.3, -0.2, 0.4)
    bearings, ranges = view_ranges(local_map, pose)
    error = ranges - true_range(ROOM, pose, bearings)
    walls = np.abs(error) < 0.05  # not the few bins at the corners
    assert np.count_nonzero(walls) >= 0.95 * len(error)
    # The view has no holes: every 1 cm of the visible walls lies within 1.5 cells of
    # a view point (one point per cell the rays meet).
    dense = np.linspace(-math.pi, math.pi, 2800, endpoint=False)
    surface = true_range(ROOM, pose, dense)[:, None] * np.column_stack(
        (np.cos(dense), np.sin(dense)))
    view = ranges[:, None] * np.column_stack((np.cos(bearings), np.sin(bearings)))
    gaps = np.min(np.hypot(*(surface[:, None, :] - view[None, :, :]).transpose(2, 0, 1)),
                  axis=1)
    assert np.max(gaps) < 0.075
    # One scan's points err by 1 cm; the map's surface, 20 scans pooled, by a few mm.
    assert np.sqrt(np.mean(error[walls] ** 2)) < 0.004
    one = scan_points(ROOM, se2.pose(), noise=0.01, seed=99)
    single = np.hypot(*one.T) - true_range(ROOM, se2.pose(), np.arctan2(one[:, 1], one[:, 0]))
    assert np.sqrt(np.mean(single ** 2)) > 0.008


def test_the_view_hides_surfaces_behind_nearer_ones():
    # A wall 1 m in front of the robot, inside the room; both are in the map (the far
    # wall seen from beside the near one), and from the origin only the near one shows.
    near = wall((1.0, -1.0), (1.0, 1.0))
    local_map = LocalMap(geometry())
    local_map.insert(scan_points(ROOM, se2.pose(2.0, 0.0, 0.0)), se2.pose(2.0, 0.0, 0.0),
                     SENSOR, BIN)
    local_map.insert(scan_points(stack(ROOM, near), se2.pose()), se2.pose(), SENSOR, BIN)
    bearings, ranges = view_ranges(local_map, se2.pose())
    ahead = np.abs(bearings) < math.atan(0.8)
    assert np.count_nonzero(ahead) >= 0.9 * 1.6 / 0.05  # a point per cell of the wall
    expected = 1.0 / np.cos(bearings[ahead])
    assert np.allclose(ranges[ahead], expected, atol=0.01)


def test_what_the_beams_see_through_fades_from_the_map():
    # A box stands in the room, then is carried away: later scans see the wall behind
    # where it stood, and the view shows the wall, not a ghost of the box.
    box = rectangle(1.5, -0.3, 1.9, 0.3)
    local_map = LocalMap(geometry())
    for _ in range(10):
        local_map.insert(scan_points(stack(ROOM, box), se2.pose()), se2.pose(), SENSOR, BIN)
    bearings, ranges = view_ranges(local_map, se2.pose())
    ahead = np.abs(bearings) < 0.1
    assert np.allclose(ranges[ahead], 1.5 / np.cos(bearings[ahead]), atol=0.02)
    for k in range(10):
        pose = se2.pose(0.0, 0.02 * k, 0.0)
        local_map.insert(scan_points(ROOM, pose), pose, SENSOR, BIN)
    bearings, ranges = view_ranges(local_map, se2.pose())
    ahead = np.abs(bearings) < 0.1
    assert np.allclose(ranges[ahead], 4.022 / np.cos(bearings[ahead]), atol=0.02)


def _reference(**changes) -> MapReference:
    config = LocalMapConfig(reference='local_map', **changes)
    return MapReference(config, LaserMounting())


def _scan(world: np.ndarray, pose) -> ScanPoints:
    points = scan_points(world, pose)
    return ScanPoints(points, np.arange(len(points)), np.hypot(*points.T))


def test_a_scan_joins_the_map_only_after_enough_motion():
    reference = _reference(map_insert_distance=0.1, map_insert_angle=0.05)
    reference.restart(_scan(ROOM, se2.pose()), se2.pose())
    assert reference.offer(_scan(ROOM, se2.pose(0.05)), se2.pose(0.05)) == 'near'
    assert reference.offer(_scan(ROOM, se2.pose(0.0, 0.0, 0.03)),
                           se2.pose(0.0, 0.0, 0.03)) == 'near'
    assert reference.offer(_scan(ROOM, se2.pose(0.12)), se2.pose(0.12)) == 'joined'
    assert reference.offer(_scan(ROOM, se2.pose(0.12, 0.0, 0.06)),
                           se2.pose(0.12, 0.0, 0.06)) == 'joined'
    reference.view(se2.pose())
    assert reference.joined == 3


def test_scans_that_fit_poorly_are_refused_then_the_map_restarts():
    reference = _reference()
    reference.restart(_scan(ROOM, se2.pose()), se2.pose())
    outcomes = [reference.offer(_scan(ROOM, se2.pose(0.2 * k)), se2.pose(0.2 * k), fits=False)
                for k in range(1, MAX_REFUSED + 1)]
    assert outcomes == ['refused'] * (MAX_REFUSED - 1) + ['restarted']
    # Restarted from the last scan: the map holds it alone.
    view = reference.view(se2.pose(0.2 * MAX_REFUSED))
    assert reference.joined == 1 and len(view) >= 0.9 * len(reference.map)
    assert reference.previous_scan is not None


def test_reset_forgets_the_map():
    reference = _reference()
    reference.restart(_scan(ROOM, se2.pose()), se2.pose())
    assert len(reference.view(se2.pose())) > 0
    reference.reset()
    assert reference.empty and len(reference.view(se2.pose())) == 0


@pytest.mark.parametrize('max_cells', [300, 2000])
def test_the_map_never_holds_more_cells_than_its_budget(max_cells):
    local_map = LocalMap(geometry(max_cells=max_cells))
    for k in range(30):
        pose = se2.pose(0.1 * math.cos(k), 0.1 * math.sin(k), 0.2 * k)
        local_map.insert(scan_points(ROOM, pose, noise=0.02, seed=k), pose, SENSOR, BIN)
        assert len(local_map) <= max_cells
    assert local_map.nbytes == LocalMap(geometry(max_cells=max_cells)).nbytes


def test_a_cleared_map_is_a_fresh_one():
    used, fresh = LocalMap(geometry(max_cells=2000)), LocalMap(geometry(max_cells=2000))
    for k in range(5):
        pose = se2.pose(0.3 * k, 0.1, 0.1 * k)
        used.insert(scan_points(ROOM, pose, noise=0.01, seed=k), pose, SENSOR, BIN)
    used.clear()
    assert len(used) == 0
    pose = se2.pose(-1.0, 0.5, 2.0)
    for local_map in (used, fresh):
        local_map.insert(scan_points(ROOM, pose, noise=0.01, seed=9), pose, SENSOR, BIN)
    (used_means, used_weights), (fresh_means, fresh_weights) = (
        m.cell_means() for m in (used, fresh))
    order_used, order_fresh = np.lexsort(used_means.T), np.lexsort(fresh_means.T)
    assert np.allclose(used_means[order_used], fresh_means[order_fresh])
    assert np.allclose(used_weights[order_used], fresh_weights[order_fresh])
    assert np.allclose(*(np.sort(view_ranges(m, pose)[1]) for m in (used, fresh)))
