"""ROS shell without DDS: parameter declarations, config files, conversions, diagnostics."""

from collections import Counter
import math
from pathlib import Path

from diagnostic_msgs.msg import DiagnosticStatus
from nav_msgs.msg import Odometry
import numpy as np
import pytest
from sensor_msgs.msg import Imu
import yaml

from laser_odom.core import se2
from laser_odom.core.configuration.node import (
    check_change, NodeConfig, parameter_specs, settings_from_params)
from laser_odom.core.parameters import flatten
from laser_odom.core.pipeline.estimate import OdometryEstimate
from laser_odom.core.scan.laser_scan import LaserMounting, LaserScan, scan_to_points
from laser_odom.ros.conversions import (
    covariance_3x3, covariance_6x6, imu_yaw_from_msg, mounting_from_transform, ns_to_stamp,
    odometry_to_msg, scan_from_msg, scan_to_msg, stamp_to_ns, UNOBSERVED_VARIANCE)
from laser_odom.ros.default_params import default_yaml
from laser_odom.ros.diagnostics import DiagnosticsReporter, Snapshot
from laser_odom.ros.parameters import descriptor

CONFIG_DIR = Path(__file__).resolve().parents[1] / 'config'
NODE_KEYS = ('/**', 'laser_odom', '/laser_odom', '/**/laser_odom')
"""YAML keys under which rcl applies a file's parameters to the node /laser_odom."""


def load_parameters(path: Path) -> dict:
    """Return the flat ``ros__parameters`` of a node parameter file."""
    document = yaml.safe_load(path.read_text())
    assert isinstance(document, dict) and len(document) == 1, path.name
    (key, body), = document.items()
    assert key in NODE_KEYS, f'{path.name}: node key {key!r} does not match /laser_odom'
    return flatten(body['ros__parameters'])


@pytest.mark.parametrize('path', sorted(CONFIG_DIR.glob('*.yaml')), ids=lambda p: p.name)
def test_every_config_file_is_valid_for_the_node(path):
    specs = {s.name: s for s in parameter_specs()}
    values = load_parameters(path)
    for name, value in values.items():
        assert name in specs or name == 'use_sim_time', f'{path.name}: unknown {name}'
        if name in specs:
            # rclpy refuses 0 for a double parameter: the types must match exactly.
            assert type(value) is type(specs[name].default), f'{path.name}: {name}={value!r}'
    merged = {s.name: s.default for s in specs.values()} | values
    settings = settings_from_params(merged)
    assert settings.pipeline.matcher == values.get('matcher', settings.pipeline.matcher)


def test_default_yaml_lists_every_parameter_with_its_default():
    values = load_parameters(CONFIG_DIR / 'default.yaml')
    defaults = {s.name: s.default for s in parameter_specs()}
    hint = 'regenerate: python -m laser_odom.ros.default_params > config/default.yaml'
    assert values == defaults, hint
    assert (CONFIG_DIR / 'default.yaml').read_text() == default_yaml(), hint


def test_descriptors_carry_description_range_and_read_only():
    specs = {s.name: s for s in parameter_specs()}
    assert {'matcher', 'odom_frame', 'base_frame', 'prior', 'laser_x', 'icp.max_iterations',
            'keyframe_distance', 'publish_tf', 'use_tf_extrinsic'} <= set(specs)
    for spec in specs.values():
        d = descriptor(spec)
        assert d.description.strip()
        if isinstance(spec.default, float) and not isinstance(spec.default, bool):
            r = d.floating_point_range[0]
            assert r.from_value <= spec.default <= r.to_value
            assert (r.from_value, r.to_value) == (spec.info.low, spec.info.high)
        elif isinstance(spec.default, int) and not isinstance(spec.default, bool):
            r = d.integer_range[0]
            assert r.from_value <= spec.default <= r.to_value and r.step == 1
    assert descriptor(specs['odom_frame']).read_only
    assert not descriptor(specs['matcher']).read_only
    assert 'plicp' in descriptor(specs['matcher']).description


def test_check_change_gives_reasons():
    specs = {s.name: s for s in parameter_specs()}
    values = {s.name: s.default for s in specs.values()}
    assert check_change(values, {'matcher': 'plicp', 'laser_yaw': 0.3}, specs) is None
    assert 'not one of' in check_change(values, {'matcher': 'gicp'}, specs)
    assert 'above the maximum' in check_change(values, {'min_inlier_ratio': 2.0}, specs)
    assert 'must not exceed' in check_change(
        values, {'diagnostics_warn_processing_time': 1.0}, specs)
    assert check_change(values, {'use_sim_time': True}, specs) is None
    # A crossed pair, one side changed or both at once (issue 39).
    assert check_change(values, {'nicp.normal_min_neighbours': 13}, specs) == (
        'nicp.normal_min_neighbours=13 must not exceed nicp.normal_neighbours=12')
    assert check_change(values, {'nicp.normal_neighbours': 6, 'nicp.normal_min_neighbours': 7},
                        specs) == ('nicp.normal_min_neighbours=7 must not exceed '
                                   'nicp.normal_neighbours=6')
    assert check_change(values, {'nicp.normal_neighbours': 6, 'nicp.normal_min_neighbours': 6},
                        specs) is None


def test_scan_round_trip_keeps_stamp_and_readings():
    ranges = np.array([1.0, np.nan, np.inf, -np.inf, 0.25, 30.5])
    scan = LaserScan(1_700_000_123_456_789_012, -1.0, 1.5, 0.5, 0.1, 30.0, ranges,
                     intensities=np.arange(6.0), frame_id='front_laser', scan_time=0.1)
    back = scan_from_msg(scan_to_msg(scan))
    assert back.stamp_ns == scan.stamp_ns and back.frame_id == 'front_laser'
    assert np.array_equal(back.ranges, ranges.astype(np.float32), equal_nan=True)
    assert np.array_equal(back.intensities, np.arange(6.0))
    assert back.angle_increment == 0.5 and back.scan_time == pytest.approx(0.1)
    for stamp in (0, 1, 999_999_999, 1_000_000_000, 1_800_000_000_123_456_789):
        assert stamp_to_ns(ns_to_stamp(stamp)) == stamp


def test_odometry_message_embeds_planar_covariance_and_never_nan():
    covariance = np.array([[0.04, 0.01, 0.002], [0.01, 0.09, 0.003], [0.002, 0.003, 0.01]])
    estimate = OdometryEstimate(5, se2.pose(1.0, -2.0, 3.0), covariance,
                                np.array([0.5, 0.0, np.nan]), np.eye(3), 'matched')
    msg = odometry_to_msg(estimate, ns_to_stamp(5), 'odom', 'base')
    full = np.asarray(msg.pose.covariance).reshape(6, 6)
    assert np.allclose(covariance_3x3(msg.pose.covariance), covariance)
    assert full[0, 5] == 0.002 and full[5, 1] == 0.003
    assert np.allclose(np.diag(full)[2:5], UNOBSERVED_VARIANCE)
    assert msg.twist.twist.linear.x == 0.0  # non-finite twist: zero, unobserved
    assert np.asarray(msg.twist.covariance)[0] == UNOBSERVED_VARIANCE
    q = msg.pose.pose.orientation
    assert se2.quaternion_to_yaw(q.x, q.y, q.z, q.w) == pytest.approx(3.0)
    assert np.all(np.isfinite(covariance_6x6(np.full((3, 3), np.nan))))
    estimate.pose = se2.pose(np.nan, 0.0, 0.0)
    assert odometry_to_msg(estimate, ns_to_stamp(5), 'odom', 'base') is None


def test_imu_without_orientation_gives_rate_only():
    msg = Imu()
    msg.orientation.z, msg.orientation.w = math.sin(0.35), math.cos(0.35)
    msg.angular_velocity.z = 0.2
    assert imu_yaw_from_msg(msg)[1] == pytest.approx(0.7)
    msg.orientation_covariance[0] = -1.0
    assert imu_yaw_from_msg(msg)[1:] == (None, 0.2)
    assert isinstance(Odometry(), Odometry)


@pytest.mark.parametrize('roll', [0.0, math.pi])
def test_mounting_from_transform_matches_scan_projection(roll):
    """A 3D base <- laser transform projects the scan exactly as the planar mounting does."""
    yaw, t = 0.7, (0.3, -0.2, 0.4)
    # q = q_z(yaw) * q_x(roll)
    cr, sr, cy, sy = math.cos(roll / 2), math.sin(roll / 2), math.cos(yaw / 2), math.sin(yaw / 2)
    q = (cy * sr, sy * sr, sy * cr, cy * cr)
    mounting, tilt = mounting_from_transform(t, q)
    assert mounting.upside_down == (roll != 0.0) and tilt == pytest.approx(0.0, abs=1e-7)
    scan = LaserScan(0, -1.0, 1.0, 0.5, 0.0, 10.0, np.array([1.0, 2.0, 3.0, 2.5, 1.5]))
    points = scan_to_points(scan, mounting).points
    angles = scan.angle_min + np.arange(5) * scan.angle_increment
    laser = np.column_stack((scan.ranges * np.cos(angles), scan.ranges * np.sin(angles),
                             np.zeros(5)))
    rz = np.array([[cy * cy - sy * sy, -2 * sy * cy, 0], [2 * sy * cy, cy * cy - sy * sy, 0],
                   [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, math.cos(roll), -math.sin(roll)],
                   [0, math.sin(roll), math.cos(roll)]])
    expected = laser @ (rz @ rx).T + np.array(t)
    assert np.allclose(points, expected[:, :2])
    assert isinstance(mounting, LaserMounting)


def _snapshot(time, received, **counts):
    return Snapshot(time, received, Counter(counts), np.array([0.01, 0.02, 0.03]), 'icp',
                    'constant_velocity', '/scan')


def test_diagnostics_levels_follow_the_last_period():
    reporter = DiagnosticsReporter('laser_odom: odometry', 'base_link', 0.0)
    config = NodeConfig()
    status = reporter.status(_snapshot(1.0, 10, scans_in=10, processed=10, matched=10),
                             config)
    assert status.level == DiagnosticStatus.OK and status.message == 'OK'
    values = {kv.key: kv.value for kv in status.values}
    assert values['input rate [Hz]'] == '10.00' and values['processing time median [ms]'] == \
        '20.00'
    status = reporter.status(_snapshot(2.0, 20, scans_in=20, processed=20, matched=17,
                                       rejected=3, rejected_low_inlier_ratio=3), config)
    assert status.level == DiagnosticStatus.WARN and '30%' in status.message
    assert {kv.key: kv.value for kv in status.values}['rejected: low_inlier_ratio'] == '3'
    status = reporter.status(_snapshot(3.0, 30, scans_in=30, processed=30, matched=21,
                                       rejected=9), config)
    assert status.level == DiagnosticStatus.ERROR
    status = reporter.status(_snapshot(4.0, 40, scans_in=35, processed=35, matched=26,
                                       rejected=9, skipped_backlog=5), config)
    assert status.level == DiagnosticStatus.WARN and 'slower' in status.message
    assert {kv.key: kv.value for kv in status.values}['skipped: skipped_backlog'] == '5'
    status = reporter.status(_snapshot(5.0, 40, scans_in=35, processed=35, matched=26,
                                       rejected=9, skipped_backlog=5), config)
    assert status.level == DiagnosticStatus.WARN and 'no scans' in status.message
