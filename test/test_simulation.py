"""Tests of the 2D simulator: exact ray casting, laser model, worlds, path and odometry."""

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from laser_odom.core import se2
from laser_odom.core.scan.laser_scan import LaserMounting, scan_to_points
from laser_odom.core.simulation import (
    EPOCH_NS, geometry as geo, get_world, LaserModel, OdometryNoise, render_scan, simulate,
    true_ranges, UnknownWorldError, world_names)
from laser_odom.core.simulation.raycast import cast_fan, cast_rays

EXACT = LaserModel(noise_sigma=0.0, dropout=0.0)
WORLD_NAMES = ['office', 'corridor', 'cluttered', 'featureless_corridor', 'campus', 'hall']
ENCLOSED_WORLDS = WORLD_NAMES[:4]
"""The indoor worlds driven gently; campus and hall have their own tests (test_worlds.py)."""


def test_registry_names_and_unknown_world():
    assert world_names() == WORLD_NAMES
    with pytest.raises(UnknownWorldError, match='valid names'):
        get_world('moon')


def test_cast_rays_against_one_wall_is_exact():
    wall = np.array([[2.0, -5.0, 2.0, 5.0]])
    angles = np.array([0.0, 0.3, -1.0, math.atan2(5.0, 2.0) + 1e-3, math.pi, math.pi / 2])
    ranges = cast_rays(np.zeros(2), angles, wall)
    assert ranges[0] == pytest.approx(2.0, abs=1e-12)
    assert ranges[1] == pytest.approx(2.0 / math.cos(0.3), abs=1e-12)
    assert ranges[2] == pytest.approx(2.0 / math.cos(1.0), abs=1e-12)
    assert np.all(np.isinf(ranges[3:]))  # past the wall's end, behind, parallel


def test_cast_rays_takes_the_nearest_wall_and_honours_max_range():
    walls = np.array([[3.0, -1.0, 3.0, 1.0], [1.5, -1.0, 1.5, 1.0], [-4.0, -1.0, -4.0, 1.0]])
    ranges = cast_rays(np.array([0.5, 0.0]), np.array([0.0, math.pi]), walls)
    np.testing.assert_allclose(ranges, [1.0, 4.5], atol=1e-12)
    limited = cast_rays(np.array([0.5, 0.0]), np.array([0.0, math.pi]), walls, max_range=2.0)
    assert limited[0] == pytest.approx(1.0) and math.isinf(limited[1])


@pytest.mark.parametrize('name', WORLD_NAMES)
def test_culled_fan_equals_brute_force_rays(name):
    world = get_world(name)
    rng = np.random.default_rng(11)
    layouts = [(-math.pi, 2 * math.pi / 360, 360), (-2.35, math.radians(0.25), 1081),
               (1.0, -math.radians(0.5), 500), (5.0, 2 * math.pi / 777, 777)]
    for origin in world.path.points[::350]:
        for start, increment, count in layouts:
            start += rng.uniform(-math.pi, math.pi)
            fan = cast_fan(origin, start, increment, count, world.segments, 20.0)
            brute = cast_rays(origin, start + np.arange(count) * increment, world.segments,
                              20.0)
            np.testing.assert_allclose(fan, brute, rtol=0.0, atol=1e-9)


def test_render_distance_to_corridor_walls_is_exact():
    pose = se2.pose(5.0, 0.3, 0.0)
    scan = render_scan('featureless_corridor', pose, EXACT)
    angles = scan.angle_min + np.arange(len(scan.ranges)) * scan.angle_increment
    left = int(np.argmin(np.abs(angles - math.pi / 2)))
    right = int(np.argmin(np.abs(angles + math.pi / 2)))
    assert scan.ranges[left] == pytest.approx(1.2, abs=1e-12)
    assert scan.ranges[right] == pytest.approx(1.8, abs=1e-12)
    tilted = int(np.argmin(np.abs(angles - math.radians(30.0))))
    assert scan.ranges[tilted] == pytest.approx(1.2 / math.sin(angles[tilted]), abs=1e-12)
    # Along the axis the corridor ends are ~95 m away: no return within 20 m.
    ahead = int(np.argmin(np.abs(angles)))
    assert math.isinf(scan.ranges[ahead]) and scan.ranges[ahead] > 0


@pytest.mark.parametrize('name', WORLD_NAMES)
def test_noise_free_points_lie_on_the_walls(name):
    world = get_world(name)
    pose = world.path.poses_at(np.array([17.0]))[0]
    points = scan_to_points(render_scan(world, pose, EXACT))
    assert len(points) > 100
    world_points = se2.transform_points(pose, points.points)
    assert geo.distance_to_segments(world_points, world.segments).max() < 1e-9


def test_laser_model_layouts():
    full = LaserModel()
    assert full.angle_increment == pytest.approx(math.radians(1.0))
    assert full.angles[0] == pytest.approx(-math.pi)
    assert full.angles[-1] == pytest.approx(math.pi - math.radians(1.0))
    hokuyo = LaserModel(beams=1081, fov=math.radians(270.0))
    assert hokuyo.angle_increment == pytest.approx(math.radians(0.25))
    assert hokuyo.angles[0] == pytest.approx(-math.radians(135.0))
    assert hokuyo.angles[-1] == pytest.approx(math.radians(135.0))
    scan = render_scan('office', se2.pose(), hokuyo)
    assert scan.angle_max == pytest.approx(math.radians(135.0))
    assert scan.frame_id == 'laser' and scan.range_max == 20.0 and scan.range_min == 0.05
    for bad in ({'beams': 1}, {'fov': 0.0}, {'min_range': 5.0, 'max_range': 4.0},
                {'noise_sigma': -1.0}, {'dropout': 1.5}, {'rate': 0.0}):
        with pytest.raises(ValueError):
            LaserModel(**bad)


def test_noise_statistics():
    laser = LaserModel(beams=3600, noise_sigma=0.02)
    pose = se2.pose(3.0, 1.0, 0.4)
    truth = true_ranges('office', pose, laser)
    rng = np.random.default_rng(7)
    errors = np.concatenate([render_scan('office', pose, laser, rng).ranges - truth
                             for _ in range(5)])
    errors = errors[np.isfinite(errors)]
    assert errors.size > 15000
    assert abs(errors.mean()) < 4.0 * 0.02 / math.sqrt(errors.size)
    assert errors.std() == pytest.approx(0.02, rel=0.03)


def test_dropouts_and_range_codes():
    laser = LaserModel(beams=3600, dropout=0.2, noise_sigma=0.0)
    scan = render_scan('office', se2.pose(3.0, 1.0, 0.0), laser, np.random.default_rng(1))
    dropped = np.isnan(scan.ranges)
    assert dropped.mean() == pytest.approx(0.2, abs=0.025)
    assert np.all(np.isfinite(scan.ranges[~dropped]))  # the office is closed, 20 m range
    inf_drop = LaserModel(beams=3600, dropout=0.2, dropout_value=math.inf)
    assert np.isinf(render_scan('office', se2.pose(3.0, 1.0, 0.0), inf_drop).ranges).any()
    # Too far gives +inf, too close gives -inf (REP-117).
    short = LaserModel(max_range=1.0, noise_sigma=0.0)
    far = render_scan('featureless_corridor', se2.pose(0.0, 0.0, 0.0), short).ranges
    assert np.all(np.isposinf(far))
    close = render_scan('featureless_corridor', se2.pose(0.0, 1.47, 0.0), EXACT)
    left = int(np.argmin(np.abs(EXACT.angles - math.pi / 2)))
    assert np.isneginf(close.ranges[left])
    assert np.isneginf(close.ranges).sum() > 0 and np.isfinite(close.ranges).sum() > 100


def test_simulation_is_deterministic_per_seed():
    laser = LaserModel(dropout=0.05)
    a = simulate('office', 5.0, laser, seed=3)
    b = simulate('office', 5.0, laser, seed=3)
    c = simulate('office', 5.0, laser, seed=4)
    for sa, sb in zip(a.scans, b.scans):
        np.testing.assert_array_equal(sa.ranges, sb.ranges)
        assert sa.stamp_ns == sb.stamp_ns
    np.testing.assert_array_equal(a.odometry.poses, b.odometry.poses)
    np.testing.assert_array_equal(a.reference.poses, c.reference.poses)
    assert not np.array_equal(a.scans[10].ranges, c.scans[10].ranges, equal_nan=True)
    assert not np.array_equal(a.odometry.poses, c.odometry.poses)


def test_simulation_stamps_and_sizes():
    data = simulate('office', 6.0, LaserModel(rate=5.0), odometry_rate=40.0)
    stamps = np.array([s.stamp_ns for s in data.scans])
    assert len(stamps) == 30 and stamps[0] == EPOCH_NS
    assert np.all(np.diff(stamps) == 200_000_000)
    np.testing.assert_array_equal(data.reference.stamps_ns, stamps)
    assert data.odometry.stamps_ns[0] == EPOCH_NS
    assert data.odometry.stamps_ns[-1] >= stamps[-1]
    assert np.all(np.diff(data.odometry.stamps_ns) == 25_000_000)
    np.testing.assert_allclose(data.reference.poses[0], [0.0, 0.0, 0.0], atol=1e-9)
    assert all(s.frame_id == 'laser' for s in data.scans)


@pytest.mark.parametrize('name', ENCLOSED_WORLDS)
def test_path_stays_in_free_space(name):
    world = get_world(name)
    path = world.path
    loop = np.vstack((path.points, path.points[:1]))
    assert not geo.polyline_crosses(loop, world.segments).any()
    assert geo.distance_to_segments(path.points, world.segments).min() >= world.min_clearance
    # The start is enclosed: every ray from it meets a wall (inside the building).
    start = path.poses_at(np.array([0.0]))[0]
    np.testing.assert_allclose(start, [0.0, 0.0, 0.0], atol=1e-9)
    assert np.all(np.isfinite(cast_rays(start[:2], np.linspace(-3.1, 3.1, 720),
                                        world.segments)))
    times = np.arange(0.0, 1.2 * path.length / 0.3, 0.05)
    v, w = path.speeds_at(times)
    assert v.max() < 0.61 and np.abs(w).max() < 0.6
    assert v[times > 5.0].min() > 0.15  # never stops after the start
    assert path.arc_length_at(times[-1:])[0] > path.length  # laps repeat


def test_featureless_corridor_has_no_features_in_range_along_the_path():
    world = get_world('featureless_corridor')
    poses = simulate(world, 120.0, EXACT).reference.poses
    assert np.abs(poses[:, 0]).max() + EXACT.max_range < world.bounds[2] - 40.0
    assert len(world.segments) == 4


@pytest.mark.parametrize('mounting', [
    LaserMounting(0.0, 0.0, math.radians(7.0)),
    LaserMounting(0.0, 0.0, 0.0, upside_down=True),
    LaserMounting(0.0, 0.0, math.radians(-12.0), upside_down=True),
])
def test_rotated_and_flipped_render_matches_scan_to_points(mounting):
    """A laser at the base origin sees the same surface points however it is turned."""
    pose = se2.pose(2.0, -0.4, 0.3)
    plain = scan_to_points(render_scan('office', pose, EXACT)).points
    mounted = scan_to_points(render_scan('office', pose, EXACT, mounting=mounting), mounting)
    assert len(mounted) == len(plain)
    gap, index = cKDTree(plain).query(mounted.points)
    assert gap.max() < 1e-9
    assert len(np.unique(index)) == len(plain)  # one-to-one


@pytest.mark.parametrize('upside_down', [False, True])
def test_offset_mounting_renders_from_the_laser_pose(upside_down):
    mounting = LaserMounting(0.3, -0.2, 0.4, upside_down)
    pose = se2.pose(1.0, 0.5, -0.2)
    scan = render_scan('office', pose, EXACT, mounting=mounting)
    base_points = scan_to_points(scan, mounting).points
    world = get_world('office')
    on_walls = geo.distance_to_segments(se2.transform_points(pose, base_points), world.segments)
    assert on_walls.max() < 1e-9
    # Beam i of the laser equals the beam that looks the same way from the laser pose.
    laser_pose = se2.compose(pose, mounting.pose)
    direction = -EXACT.angles if upside_down else EXACT.angles
    expected = cast_rays(laser_pose[:2], laser_pose[2] + direction, world.segments, 20.0)
    expected[expected > EXACT.max_range] = np.inf
    np.testing.assert_allclose(scan.ranges, expected, atol=1e-12)
    assert not np.allclose(scan.ranges, render_scan('office', pose, EXACT).ranges)


def test_wheel_odometry_noise_model():
    perfect = simulate('featureless_corridor', 20.0, EXACT,
                       odometry_noise=OdometryNoise().scaled(0.0))
    truth = perfect.reference
    for stamp, p in zip(truth.stamps_ns, truth.poses):
        np.testing.assert_allclose(perfect.odometry.interpolate(int(stamp)), p, atol=1e-9)
    # A pure 10 % wheel-diameter error on a straight leg scales the distance by 1.1.
    scaled = simulate('featureless_corridor', 20.0, EXACT,
                      odometry_noise=OdometryNoise(0.1, 0.0, 0.0, 0.0, 0.0, 0.0))
    end = scaled.odometry.interpolate(int(truth.stamps_ns[-1]))
    assert end[0] == pytest.approx(1.1 * truth.poses[-1, 0], rel=1e-6)
    assert abs(end[1]) < 1e-9
    # The default model drifts, by a plausible few percent of the distance.
    noisy = simulate('office', 60.0, EXACT)
    driven = np.hypot(*np.diff(noisy.reference.poses[:, :2], axis=0).T).sum()
    drift = np.hypot(*(noisy.odometry.interpolate(int(noisy.reference.stamps_ns[-1]))[:2]
                       - noisy.reference.poses[-1, :2]))
    assert 0.001 * driven < drift < 0.05 * driven
