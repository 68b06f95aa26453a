"""Tests of the ROS 2 bag writer, the TUM reader/writer and ``laser_odom_simulate``."""

import math
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores

from laser_odom.core import se2
from laser_odom.core.scan.laser_scan import LaserScan
from laser_odom.core.simulation import LaserModel, simulate
from laser_odom.core.trajectory import Trajectory
from laser_odom.io.bag_writer import write_bag
from laser_odom.io.errors import BagWriteError, OutputExistsError
from laser_odom.io.tum import read_tum, TumFormatError, write_tum
from laser_odom.tools.simulate import main as simulate_main

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


@pytest.fixture(scope='module')
def dataset():
    """Return 4 s of the office simulation with dropouts (NaN) and out-of-range (inf)."""
    return simulate('office', 4.0, LaserModel(dropout=0.05, max_range=6.0), seed=5,
                    odometry_rate=20.0)


def read_bag(path: Path) -> dict:
    """Return ``{topic: [(bag_time, message), ...]}`` and the overall time order."""
    out: dict = {}
    order = []
    with Reader(path) as reader:
        for connection, timestamp, raw in reader.messages():
            msg = TYPESTORE.deserialize_cdr(raw, connection.msgtype)
            out.setdefault(connection.topic, []).append((timestamp, msg))
            order.append(timestamp)
        out['_types'] = {c.topic: c.msgtype for c in reader.connections}
    out['_order'] = order
    return out


def stamp_ns(header) -> int:
    """Return a header stamp in nanoseconds."""
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap'])
def test_bag_round_trip(tmp_path, dataset, storage):
    covariance = np.tile(np.diag([0.01, 0.02, 0.003]), (len(dataset.odometry), 1, 1))
    covariance[:, 0, 2] = covariance[:, 2, 0] = 0.001
    path = tmp_path / 'sim'
    write_bag(path, dataset.scans, odometry={'/odom': dataset.odometry},
              poses={'/truth': dataset.reference}, storage=storage,
              covariances={'/odom': covariance}, frame_ids={'/truth': 'map'})
    bag = read_bag(path)
    assert bag['_types'] == {'/scan': 'sensor_msgs/msg/LaserScan',
                             '/odom': 'nav_msgs/msg/Odometry',
                             '/truth': 'geometry_msgs/msg/PoseStamped'}
    assert [len(bag[t]) for t in ('/scan', '/odom', '/truth')] == [40, 79, 40]
    assert bag['_order'] == sorted(bag['_order'])
    assert list(path.parent.iterdir()) == [path]  # no staging directory left behind

    for scan, (bag_time, msg) in zip(dataset.scans, bag['/scan']):
        assert bag_time == stamp_ns(msg.header) == scan.stamp_ns
        assert msg.header.frame_id == 'laser'
        np.testing.assert_array_equal(msg.ranges, scan.ranges.astype(np.float32))
        assert msg.angle_increment == pytest.approx(scan.angle_increment, rel=1e-7)
        assert msg.range_max == pytest.approx(6.0) and msg.scan_time == pytest.approx(0.1)
    ranges = np.concatenate([m.ranges for _, m in bag['/scan']])
    assert np.isnan(ranges).any() and np.isposinf(ranges).any()

    odom = bag['/odom']
    for k, (bag_time, msg) in enumerate(odom):
        assert bag_time == stamp_ns(msg.header) == dataset.odometry.stamps_ns[k]
        q = msg.pose.pose.orientation
        pose = [msg.pose.pose.position.x, msg.pose.pose.position.y,
                se2.quaternion_to_yaw(q.x, q.y, q.z, q.w)]
        np.testing.assert_allclose(pose, dataset.odometry.poses[k], atol=1e-12)
        assert msg.header.frame_id == 'odom' and msg.child_frame_id == 'base_link'
    cov = odom[3][1].pose.covariance.reshape(6, 6)
    assert cov[0, 0] == 0.01 and cov[1, 1] == 0.02 and cov[5, 5] == 0.003
    assert cov[0, 5] == cov[5, 0] == 0.001 and cov[2, 2] == 0.0
    # The twist is the base-frame velocity: the robot drives forward, never sideways.
    step = se2.relative(dataset.odometry.poses[9], dataset.odometry.poses[10])
    twist = odom[10][1].twist.twist
    assert twist.linear.x == pytest.approx(step[0] / 0.05, rel=1e-9)
    assert twist.angular.z == pytest.approx(step[2] / 0.05, rel=1e-6, abs=1e-12)
    speeds = np.array([m.twist.twist.linear.x for _, m in odom[20:]])
    assert 0.2 < speeds.mean() < 0.6

    for k, (bag_time, msg) in enumerate(bag['/truth']):
        assert bag_time == dataset.reference.stamps_ns[k] and msg.header.frame_id == 'map'
        assert msg.pose.position.x == pytest.approx(dataset.reference.poses[k, 0], abs=1e-12)


def test_bag_writer_refuses_to_overwrite(tmp_path, dataset):
    path = tmp_path / 'existing'
    path.mkdir()
    (path / 'keep.txt').write_text('mine')
    with pytest.raises(OutputExistsError, match='exists already'):
        write_bag(path, dataset.scans)
    assert (path / 'keep.txt').read_text() == 'mine'
    with pytest.raises(BagWriteError, match='does not exist'):
        write_bag(tmp_path / 'missing' / 'bag', dataset.scans)
    with pytest.raises(ValueError, match='storage'):
        write_bag(tmp_path / 'x', dataset.scans, storage='zip')
    with pytest.raises(ValueError, match='twice'):
        write_bag(tmp_path / 'x', dataset.scans, odometry={'/scan': dataset.odometry})
    assert sorted(p.name for p in tmp_path.iterdir()) == ['existing']


def test_failed_write_leaves_no_partial_bag(tmp_path, dataset):
    bad = LaserScan(stamp_ns=dataset.scans[-1].stamp_ns + 1, angle_min=0.0, angle_max=1.0,
                    angle_increment=0.5, range_min=0.1, range_max=5.0,
                    ranges=np.ones(3), frame_id=None)
    with pytest.raises(Exception):
        write_bag(tmp_path / 'bag', [*dataset.scans, bad])
    assert list(tmp_path.iterdir()) == []


def test_tum_round_trip_is_exact(tmp_path):
    stamps = np.array([1_700_000_000_123_456_789, 1_700_000_000_200_000_001, 5], np.int64)
    stamps.sort()
    poses = np.array([[1.5, -2.25, 0.3], [1e-9, 4.0, -math.pi + 1e-6], [-3.0, 0.0, 3.1]])
    path = tmp_path / 'traj.tum'
    write_tum(path, Trajectory(stamps, poses))
    text = path.read_text().splitlines()
    assert text[0].startswith('#') and text[1].split()[0] == '0.000000005'
    assert text[2].split()[0] == '1700000000.123456789'
    back = read_tum(path)
    np.testing.assert_array_equal(back.stamps_ns, stamps)
    np.testing.assert_allclose(back.poses[:, :2], poses[:, :2], atol=1e-9)
    np.testing.assert_allclose(se2.wrap_angle(back.poses[:, 2] - poses[:, 2]), 0.0, atol=1e-9)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['traj.tum']
    with pytest.raises(OutputExistsError):
        write_tum(path, Trajectory(), overwrite=False)
    write_tum(path, Trajectory())
    assert len(read_tum(path)) == 0


@pytest.mark.parametrize('line, message', [
    ('1.0 2 3 0 0 0 0', 'expected 8 fields'),
    ('1.0 2 x 0 0 0 0 1', 'not a number'),
    ('1.0 2 3 0 0 0 0 0', 'zero quaternion'),
    ('1.0 nan 3 0 0 0 0 1', 'non-finite'),
    ('0.5 0 0 0 0 0 0 1', r'stamp 0.500000000 is not after the one before it \(0.900000000\)'),
    ('9e-1 0 0 0 0 0 0 1', r'stamp 0.900000000 is not after the one before it \(0.900000000\)'),
])
def test_tum_errors_name_the_line(tmp_path, line, message):
    path = tmp_path / 'bad.tum'
    path.write_text(f'# comment\n\n0.9 0 0 0 0 0 0 1\n{line}\n')
    with pytest.raises(TumFormatError, match=f'bad.tum:4: {message}'):
        read_tum(path)


def test_tum_reads_other_tools_files(tmp_path):
    path = tmp_path / 'evo.txt'
    half = 0.5 * 0.7
    path.write_text(f'# from evo\n1305031102.175304 1.0 2.0 0.1 0 0 {math.sin(half)} '
                    f'{math.cos(half)}\n1305031102.2 1e-3 -2 0 0 0 0 -1\n')
    traj = read_tum(path)
    assert traj.stamps_ns[0] == 1_305_031_102_175_304_000
    np.testing.assert_allclose(traj.poses, [[1.0, 2.0, 0.7], [1e-3, -2.0, 0.0]], atol=1e-12)


def test_simulate_command(tmp_path, capsys):
    out = tmp_path / 'demo'
    args = [str(out), '--duration', '3', '--beams', '180', '--fov', '270', '--seed', '2',
            '--storage', 'mcap', '--laser-x', '0.2', '--laser-upside-down']
    assert simulate_main(args) == 0
    summary = capsys.readouterr().out.strip()
    assert summary.count('\n') == 0 and '30 scans' in summary and 'upside down' in summary
    bag = read_bag(out)
    assert [len(bag[t]) for t in ('/scan', '/ground_truth', '/odom')] == [30, 30, 146]
    assert len(bag['/scan'][0][1].ranges) == 180
    assert bag['/scan'][0][1].angle_min == pytest.approx(-math.radians(135.0))
    truth = read_tum(tmp_path / 'demo.tum')
    assert len(truth) == 30
    gt = bag['/ground_truth']
    assert gt[29][1].pose.pose.position.x == pytest.approx(truth.poses[29, 0], abs=1e-9)
    assert gt[0][1].header.frame_id == 'map'

    assert simulate_main([str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count('\n') == 0 and 'exists already' in err
    assert simulate_main([str(tmp_path / 'other'), '--tum', str(tmp_path / 'demo.tum')]) == 2
    assert not (tmp_path / 'other').exists()
    assert simulate_main([str(tmp_path / 'nodir' / 'bag')]) == 2
    assert 'does not exist' in capsys.readouterr().err
    for bad in (['--beams', '1'], ['--world', 'moon'], ['--dropout', '2'], ['--fov', '0'],
                ['--min-range', '30']):
        with pytest.raises(SystemExit) as exit_info:
            simulate_main([str(tmp_path / 'bad'), *bad])
        assert exit_info.value.code == 2
