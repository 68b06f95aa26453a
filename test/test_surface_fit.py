"""The map match's last refinement on the cells' own surfaces (local_map.surface_fit)."""

import math

import numpy as np
from test_local_map import _reference, _scan, BIN, geometry, ROOM, scan_points, SENSOR

from laser_odom.core import se2
from laser_odom.core.registration.local_map.map import LocalMap
from laser_odom.core.registration.local_map.reference import MAX_SURFACE_TURN
from laser_odom.core.registration.local_map.surface_fit import MIN_PAIRS
from laser_odom.core.simulation.geometry import stack, wall


def room_map(scans: int = 10) -> LocalMap:
    """Return a map of the room from ``scans`` noisy scans taken at the origin."""
    local_map = LocalMap(geometry())
    for seed in range(scans):
        local_map.insert(scan_points(ROOM, se2.pose(), noise=0.01, seed=seed), se2.pose(),
                         SENSOR, BIN)
    return local_map


def test_a_pose_a_few_centimetres_off_is_refined_onto_the_walls():
    local_map = room_map()
    truth = se2.pose(0.4, -0.3, 0.25)
    points = scan_points(ROOM, truth, noise=0.01, seed=77)
    for offset in ([0.03, -0.02, math.radians(0.8)], [-0.04, 0.03, math.radians(-1.2)]):
        start = np.asarray(truth) + offset
        refined, pairs = local_map.fit_to_surfaces(points, start)
        assert pairs > 0.8 * len(points)
        error = se2.relative(truth, refined)
        assert math.hypot(error[0], error[1]) < 0.004
        assert abs(math.degrees(error[2])) < 0.05


def test_the_correct_pose_stays_where_it_is():
    local_map = room_map()
    truth = se2.pose(-0.5, 0.6, -0.4)
    refined, _ = local_map.fit_to_surfaces(scan_points(ROOM, truth, noise=0.01, seed=5),
                                           truth)
    error = se2.relative(truth, refined)
    assert math.hypot(error[0], error[1]) < 0.004
    assert abs(math.degrees(error[2])) < 0.05


def test_points_far_from_the_map_leave_the_pose_as_it_was():
    local_map = room_map(1)
    far = scan_points(ROOM, se2.pose(), noise=0.01, seed=3) + 40.0  # nowhere near a cell
    start = se2.pose(0.1, 0.2, 0.3)
    refined, pairs = local_map.fit_to_surfaces(far, start)
    assert pairs < MIN_PAIRS
    np.testing.assert_array_equal(refined, start)


def test_the_map_refines_a_step_by_less_than_a_cell_and_refuses_a_larger_move():
    """A move beyond a cell changed the pairing: another minimum, and the step stands."""
    reference = _reference()
    reference.restart(_scan(ROOM, se2.pose()), se2.pose())
    view_pose = se2.pose(0.1, 0.0, 0.05)
    truth = se2.pose(0.35, -0.2, 0.2)
    true_step = se2.relative(view_pose, truth)
    points = scan_points(ROOM, truth, noise=0.005, seed=11)
    near = reference.refine_step(points, view_pose, np.asarray(true_step) + [0.02, 0.0, 0.005])
    error = se2.relative(true_step, near)
    assert math.hypot(error[0], error[1]) < 0.005 and abs(error[2]) < math.radians(0.1)
    far = np.asarray(true_step) + [0.0, 0.09, 0.0]  # the fit would move it 9 cm
    assert reference.refine_step(points, view_pose, far) is None
    turned = np.asarray(true_step) + [0.0, 0.0, MAX_SURFACE_TURN * 1.5]
    assert reference.refine_step(points, view_pose, turned) is None


def corridor(stub_at: float) -> np.ndarray:
    """Two walls 2 m apart, farther than the scanner reaches, and one door frame."""
    return stack(wall((-100.0, -1.0), (100.0, -1.0)), wall((-100.0, 1.0), (100.0, 1.0)),
                 wall((stub_at, 1.0), (stub_at, 0.6)))


def test_a_corridor_keeps_the_matchers_position_along_its_axis():
    """The cells measure the axis by one door frame only: no correction along it.

    The map put the frame 4 cm from where the scan sees it (scans that joined while the
    pose erred along the axis). Gauss-Newton moves the pose 3 cm along the axis to that
    frame; with ``map_surface_weak_share`` 0.05 the start stands there, and across the
    axis and in heading the walls still correct it.
    """
    local_map = LocalMap(geometry())
    for seed in range(10):
        local_map.insert(scan_points(corridor(2.04), se2.pose(), noise=0.005, seed=seed),
                         se2.pose(), SENSOR, BIN)
    points = scan_points(corridor(2.0), se2.pose(), noise=0.005, seed=99)
    start = se2.pose(0.0, 0.02, math.radians(0.5))
    assert abs(local_map.fit_to_surfaces(points, start)[0][0]) > 0.02  # every direction
    refined, pairs = local_map.fit_to_surfaces(points, start, 0.05)
    assert pairs > 0.8 * len(points)
    assert abs(refined[0]) < 0.002, refined  # along the axis: the start stands
    assert abs(refined[1]) < 0.004 and abs(math.degrees(refined[2])) < 0.05, refined
