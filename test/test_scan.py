"""LaserScan -> points: angles, increments, range limits, invalid readings, mounting."""

import math

import numpy as np

from laser_odom.core import se2
from laser_odom.core.scan import LaserMounting, LaserScan, scan_to_points


def make_scan(ranges, angle_min=-math.pi / 2, increment=math.pi / 2, range_min=0.1,
              range_max=10.0):
    ranges = np.asarray(ranges, dtype=float)
    return LaserScan(stamp_ns=5, angle_min=angle_min,
                     angle_max=angle_min + increment * (len(ranges) - 1),
                     angle_increment=increment, range_min=range_min, range_max=range_max,
                     ranges=ranges)


def test_angles_and_points():
    pts = scan_to_points(make_scan([1.0, 2.0, 3.0]))
    assert np.allclose(pts.points, [[0.0, -1.0], [2.0, 0.0], [0.0, 3.0]], atol=1e-12)
    assert list(pts.beam_index) == [0, 1, 2]
    assert pts.stamp_ns == 5


def test_negative_increment_sweeps_clockwise():
    pts = scan_to_points(make_scan([1.0, 2.0, 3.0], angle_min=math.pi / 2,
                                   increment=-math.pi / 2))
    assert np.allclose(pts.points, [[0.0, 1.0], [2.0, 0.0], [0.0, -3.0]], atol=1e-12)


def test_invalid_readings_are_dropped_and_indices_kept():
    ranges = [1.0, np.nan, np.inf, -np.inf, 0.05, 11.0, 2.0]
    pts = scan_to_points(make_scan(ranges, increment=0.1))
    assert list(pts.beam_index) == [0, 6]
    assert np.allclose(pts.ranges, [1.0, 2.0])
    assert np.all(np.isfinite(pts.points))


def test_range_limits_are_inclusive():
    pts = scan_to_points(make_scan([0.1, 10.0], increment=0.1))
    assert len(pts) == 2


def test_mounting_offset_and_yaw():
    mount = LaserMounting(x=0.2, y=-0.1, yaw=math.pi / 2)
    pts = scan_to_points(make_scan([1.0, 2.0, 3.0]), mount)
    raw = scan_to_points(make_scan([1.0, 2.0, 3.0]))
    assert np.allclose(pts.points, se2.transform_points(se2.pose(0.2, -0.1, math.pi / 2),
                                                        raw.points))


def test_upside_down_mirrors_the_scan():
    mount = LaserMounting(upside_down=True)
    pts = scan_to_points(make_scan([1.0, 2.0, 3.0]), mount)
    assert np.allclose(pts.points, [[0.0, 1.0], [2.0, 0.0], [0.0, -3.0]], atol=1e-12)


def test_tree_is_built_once():
    pts = scan_to_points(make_scan([1.0, 2.0, 3.0]))
    assert pts.bearing_index is pts.bearing_index
