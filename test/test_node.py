"""The laser_odom node over real DDS, in its own process, fed simulated scans.

One ROS domain per test module (random, 1..200) keeps parallel runs apart. The main
node is started from ``config/default.yaml``; later tests continue its scan sequence
(reset, set_pose, live parameters, backlog), so they run in file order.
"""

import os
import subprocess
import sys
import time

from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from node_harness import (
    call, imu_msg, latest_status, NodeProcess, odometry_msg, odometry_pose, OdometryClient,
    pose_error, ROOT, STARTUP_TIMEOUT, TEST_WORLD, unique_domain_id)
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from sensor_msgs.msg import Imu
from std_srvs.srv import Trigger
import yaml

from laser_odom.core import se2
from laser_odom.core.matchers import matcher_names
from laser_odom.core.scan.laser_scan import LaserMounting
from laser_odom.core.simulation import EPOCH_NS, LaserModel, OdometryNoise, simulate
from laser_odom.ros import extrinsic
from laser_odom.ros.conversions import (
    ns_to_stamp, planar_pose_msg, scan_to_msg, UNOBSERVED_VARIANCE)

DOMAIN = unique_domain_id()
MATCHER = 'plicp'
"""Point-to-line ICP tracks the test room to about a centimetre over 12 s."""
SECOND = 1_000_000_000
STATUS = 'laser_odom: odometry'
DEFAULT_YAML = str(ROOT / 'config' / 'default.yaml')


@pytest.fixture(scope='module')
def dataset():
    """Return 12 s of the test room: scans, ground truth, noisy wheel odometry."""
    return simulate(TEST_WORLD, 12.0, LaserModel(), seed=3,
                    odometry_noise=OdometryNoise().scaled(5.0))


@pytest.fixture(scope='module')
def main_node(peer):
    """Start the node from config/default.yaml (matcher overridden) and wait for it."""
    process = NodeProcess(DOMAIN, ['--params-file', DEFAULT_YAML, '-p', f'matcher:={MATCHER}'])
    client = OdometryClient(peer)
    assert client.wait_ready(), process.output()
    yield process, client
    process.interrupt()


@pytest.fixture(scope='module')
def main_run(main_node, dataset):
    """Send the first 60 scans one at a time; return the stamps and the node's replies."""
    process, client = main_node
    scans = dataset.scans[:60]
    replies = [client.send(scan) for scan in scans]
    client.peer.spin_for(0.5)  # room for duplicates to show up, if there were any
    return [s.stamp_ns for s in scans], replies


@pytest.mark.parametrize('arguments, words', [
    (['-p', 'matcher:=nope'], ['matcher', 'not one of', *matcher_names()]),
    (['-p', 'min_inlier_ratio:=1.5'], ['min_inlier_ratio', 'above the maximum']),
    (['--params-file', '{tmp}/text.yaml'], ['laser_x', 'must be a number', 'left']),
    (['--params-file', '{tmp}/missing.yaml'], ['params file not found', 'missing.yaml']),
])
def test_bad_parameter_stops_start_up_with_one_line(arguments, words, tmp_path):
    (tmp_path / 'text.yaml').write_text('/**:\n  ros__parameters:\n    laser_x: left\n')
    arguments = [a.format(tmp=tmp_path) for a in arguments]
    result = subprocess.run(
        [sys.executable, '-m', 'laser_odom.ros.node', '--ros-args', *arguments],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
        env=dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN), PYTHONPATH=str(ROOT)))
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.returncode == 2
    assert len(lines) == 1, result.stderr
    assert all(word in lines[0] for word in words), lines[0]
    assert 'Traceback' not in result.stdout + result.stderr


def test_every_scan_yields_one_odometry_and_one_pose(main_node, main_run):
    _, client = main_node
    stamps, _ = main_run
    assert client.order == stamps
    for stamp in stamps:
        assert len(client.odom[stamp]) == 1 and len(client.pose[stamp]) == 1
        odom, pose = client.odom[stamp][0], client.pose[stamp][0]
        assert (odom.header.frame_id, odom.child_frame_id) == ('odom', 'base_link')
        assert pose.header.frame_id == 'odom'
        assert pose.header.stamp == odom.header.stamp == ns_to_stamp(stamp)
        assert np.allclose(odometry_pose(pose), odometry_pose(odom))
        for covariance in (odom.pose.covariance, odom.twist.covariance):
            c = np.asarray(covariance).reshape(6, 6)
            assert np.all(np.isfinite(c)) and np.allclose(c, c.T)
            assert np.allclose(np.diag(c)[2:5], UNOBSERVED_VARIANCE)
        twist = odom.twist.twist
        assert np.all(np.isfinite([twist.linear.x, twist.linear.y, twist.angular.z]))


def test_pose_tracks_ground_truth(main_run, dataset):
    stamps, replies = main_run
    truth = dataset.reference.poses
    errors = np.array([pose_error(odometry_pose(r), se2.relative(truth[0], truth[i]))
                       for i, r in enumerate(replies)])
    assert se2.relative(truth[0], truth[len(replies) - 1])[0] > 1.0  # it did drive
    assert errors[:, 0].max() < 0.03 and errors[:, 1].max() < 0.01, errors.max(axis=0)
    # Twist in base_link matches the true forward speed (finite differences).
    speed = np.hypot(*np.diff(truth[:len(replies), :2], axis=0).T) / 0.1
    vx = np.array([r.twist.twist.linear.x for r in replies[1:]])
    assert np.median(np.abs(vx - speed)) < 0.03


def test_diagnostics_at_one_hertz_with_counters(peer, main_run):
    stamps, _ = main_run
    assert peer.spin_until(lambda: len(peer.statuses(STATUS)) >= 4, 10.0)
    times = np.array([t for t, _, _ in peer.statuses(STATUS)])
    assert 0.8 < np.median(np.diff(times)) < 1.25
    values, status = latest_status(
        peer, STATUS, lambda v, s: v['scans processed'] == str(len(stamps)))
    assert values['matcher'] == MATCHER and values['prior'] == 'constant_velocity'
    assert values['scans received'] == values['scans in'] == str(len(stamps))
    assert values['scans skipped'] == values['failed matches'] == '0'
    assert int(values['degenerate matches']) == 0
    median = float(values['processing time median [ms]'])
    assert 0.0 < median <= float(values['processing time p95 [ms]'])
    assert max(float(v['input rate [Hz]']) for _, v, _ in peer.statuses(STATUS)) > 1.0
    # Once the scans stop, the status says so.
    values, status = latest_status(peer, STATUS, lambda v, s: v['input rate [Hz]'] == '0.00')
    assert status.level == status.WARN and 'no scans' in status.message


def test_reset_and_set_pose_restart_integration(peer, main_node, main_run, dataset):
    process, client = main_node
    truth = dataset.reference.poses
    reset = peer.node.create_client(Trigger, '/laser_odom/reset')
    assert reset.wait_for_service(timeout_sec=15.0)
    assert call(peer, reset.call_async(Trigger.Request())).success
    replies = [client.send(dataset.scans[i]) for i in range(60, 70)]
    assert np.allclose(odometry_pose(replies[0]), 0.0, atol=1e-9)
    for i, reply in zip(range(60, 70), replies):
        expected = se2.relative(truth[60], truth[i])
        assert pose_error(odometry_pose(reply), expected)[0] < 0.02

    start = se2.pose(2.0, -1.0, 0.5)
    msg = PoseWithCovarianceStamped()
    msg.header.frame_id = 'odom'
    msg.pose.pose = planar_pose_msg(start)
    covariance = np.zeros((6, 6))
    covariance[0, 0], covariance[1, 1], covariance[5, 5] = 0.04, 0.09, 0.01
    msg.pose.covariance = covariance.reshape(-1).tolist()
    publisher = peer.node.create_publisher(PoseWithCovarianceStamped, '/laser_odom/set_pose', 10)
    assert peer.spin_until(lambda: publisher.get_subscription_count() >= 1, 15.0)
    publisher.publish(msg)
    assert process.wait_for_output('restarted from x=2.000 y=-1.000 yaw=0.500', 15.0)
    replies = [client.send(dataset.scans[i]) for i in range(70, 80)]
    assert np.allclose(odometry_pose(replies[0]), start, atol=1e-9)
    first = np.asarray(replies[0].pose.covariance).reshape(6, 6)
    assert np.allclose(np.diag(first)[[0, 1, 5]], [0.04, 0.09, 0.01])
    for i, reply in zip(range(70, 80), replies):
        expected = se2.compose(start, se2.relative(truth[70], truth[i]))
        assert pose_error(odometry_pose(reply), expected)[0] < 0.02


def test_live_parameters_are_validated_and_applied(peer, main_node, main_run, dataset):
    process, client = main_node
    parameters = AsyncParameterClient(peer.node, '/laser_odom')
    assert parameters.wait_for_services(timeout_sec=15.0)

    def set_value(name, value):
        result = call(peer, parameters.set_parameters([Parameter(name, value=value)]))
        return result.results[0]

    for name, value, words in [
            ('min_inlier_ratio', 1.5, ['min_inlier_ratio', 'above the maximum']),
            ('plicp.max_iterations', 0, ['plicp.max_iterations', 'below the minimum']),
            ('prior', 'gps', ['not one of', 'constant_velocity']),
            ('matcher', 'nope', matcher_names()),
            ('odom_frame', 'map', ['read-only']),
            ('diagnostics_warn_failure_rate', 0.9, ['must not exceed']),
            ('nicp.normal_min_neighbours', 13,
             ['nicp.normal_min_neighbours=13 must not exceed nicp.normal_neighbours=12'])]:
        result = set_value(name, value)
        assert not result.successful and all(w in result.reason for w in words), result.reason

    assert set_value('plicp.max_iterations', 25).successful
    got = call(peer, parameters.get_parameters(['plicp.max_iterations'])).values[0]
    assert got.integer_value == 25

    # Choosing a prior subscribes to its topic; leaving it unsubscribes.
    assert set_value('prior', 'imu').successful
    assert peer.spin_until(lambda: peer.node.count_subscribers('/imu') == 1, 15.0)
    assert set_value('prior', 'constant_velocity').successful
    assert peer.spin_until(lambda: peer.node.count_subscribers('/imu') == 0, 15.0)

    target = next(m for m in ('nicp', 'imls', 'icp') if m in matcher_names())
    # The run goes on from the newest scan answered (79 after the reset test; with
    # pytest-xdist that test may run on another worker, with a node of its own).
    done = max(i for i, scan in enumerate(dataset.scans) if scan.stamp_ns in client.odom)
    last = odometry_pose(client.odom[dataset.scans[done].stamp_ns][-1])
    assert set_value('matcher', target).successful
    truth = dataset.reference.poses
    for i in range(done + 1, done + 11):
        expected = se2.compose(last, se2.relative(truth[done], truth[i]))
        assert pose_error(odometry_pose(client.send(dataset.scans[i])), expected)[0] < 0.05
    latest_status(peer, STATUS, lambda v, s: v['matcher'] == target)

    assert set_value('diagnostics_warn_processing_time', 0.0).successful
    assert set_value('diagnostics_error_processing_time', 0.0).successful
    _, status = latest_status(peer, STATUS, lambda v, s: s.level == s.ERROR)
    assert 'processing time' in status.message
    assert set_value('diagnostics_error_processing_time', 0.5).successful
    assert set_value('diagnostics_warn_processing_time', 0.1).successful


def test_slow_processing_drops_old_scans_instead_of_queueing(peer, main_node):
    """A burst of heavy scans: the newest is processed, every other one is counted."""
    process, client = main_node
    heavy = simulate(TEST_WORLD, 1.0, LaserModel(beams=8000), seed=4,
                     start_ns=EPOCH_NS + 100 * SECOND)
    reset = peer.node.create_client(Trigger, '/laser_odom/reset')
    assert call(peer, reset.call_async(Trigger.Request())).success
    client.send(heavy.scans[0])

    def counts() -> tuple[int, int]:
        reports = len(peer.statuses(STATUS))
        assert peer.spin_until(lambda: len(peer.statuses(STATUS)) >= reports + 2, 10.0)
        values = peer.statuses(STATUS)[-1][1]
        return (int(values.get('skipped: skipped_backlog', 0)),
                int(values.get('skipped: missed_scans', 0)))

    backlog_before, missed_before = counts()
    burst = heavy.scans[1:]  # stamps within max_scan_gap of each other: gaps are counted
    messages = [scan_to_msg(scan) for scan in burst]
    for msg in messages:  # 2 ms apart: each 8000-beam match takes some 15 ms or more,
        client.scan_pub.publish(msg)  # so scans arrive, and are overwritten, meanwhile
        time.sleep(0.002)
    stamps = [s.stamp_ns for s in burst]
    assert peer.spin_until(lambda: stamps[-1] in client.odom, 60.0)
    peer.spin_for(0.5)
    answered = [s for s in client.order if s in set(stamps)]
    assert answered == sorted(set(answered))  # at most one reply each, in order
    assert answered[-1] == stamps[-1]  # the newest scan is always processed
    backlog, missed = counts()
    dropped = (backlog - backlog_before) + (missed - missed_before)
    # Every scan of the burst was either processed or counted as skipped.
    assert len(answered) + dropped == len(burst), (answered, backlog, missed)
    # Those published while the first was matched were dropped, not queued: overwritten
    # in the node's one-scan slot (skipped_backlog) or, on a loaded machine, lost
    # before the node's callback ran (seen as a stamp gap: missed_scans).
    assert dropped > 0 and len(answered) < len(burst), (answered, backlog, missed)


def test_ctrl_c_while_matching_exits_cleanly(peer, main_node):
    process, client = main_node
    heavy = simulate(TEST_WORLD, 1.0, LaserModel(beams=2000), seed=7,
                     start_ns=EPOCH_NS + 200 * SECOND)
    for scan in heavy.scans:
        client.scan_pub.publish(scan_to_msg(scan))
        peer.spin_for(0.01)
    assert peer.spin_until(lambda: any(s.stamp_ns in client.odom for s in heavy.scans), 30.0)
    assert process.interrupt() == 0
    assert 'Traceback' not in process.output() and '[ERROR]' not in process.output()


def test_laser_mounting_gives_base_frame_odometry(peer):
    mountings = {'offset': LaserMounting(0.3, -0.1, 0.5, False),
                 'flipped': LaserMounting(-0.2, 0.15, -2.0, True)}
    nodes, clients, data = {}, {}, {}
    try:
        for ns, m in mountings.items():
            nodes[ns] = NodeProcess(DOMAIN, [
                '-r', f'__ns:=/{ns}', '-p', f'matcher:={MATCHER}', '-p', f'laser_x:={m.x}',
                '-p', f'laser_y:={m.y}', '-p', f'laser_yaw:={m.yaw}',
                '-p', f'laser_upside_down:={str(m.upside_down).lower()}'])
            clients[ns] = OdometryClient(peer, f'/{ns}')
            data[ns] = simulate(TEST_WORLD, 6.0, LaserModel(), seed=5, mounting=m)
        for ns in mountings:
            assert clients[ns].wait_ready(), nodes[ns].output()
        for ns, m in mountings.items():
            truth = data[ns].reference.poses
            laser = np.array([se2.compose(p, m.pose) for p in truth])
            # The laser's own path differs from the base's: the test can tell them apart.
            laser_motion = [se2.relative(laser[0], q) for q in laser]
            base_motion = [se2.relative(truth[0], q) for q in truth]
            assert max(pose_error(a, b)[0] for a, b in zip(laser_motion, base_motion)) > 0.2
            for i, scan in enumerate(data[ns].scans):
                error = pose_error(odometry_pose(clients[ns].send(scan)), base_motion[i])
                assert error[0] < 0.03 and error[1] < 0.01, (ns, i, error)
    finally:
        for process in nodes.values():
            process.interrupt()


def test_odometry_and_imu_priors(peer, dataset):
    scans, truth = dataset.scans[:60], dataset.reference.poses
    wheel = dataset.odometry
    imu_stamps = np.arange(scans[0].stamp_ns - SECOND // 2, scans[-1].stamp_ns + SECOND,
                           SECOND // 100)
    yaw = np.unwrap(TEST_WORLD.path.poses_at((imu_stamps - EPOCH_NS) * 1e-9)[:, 2])
    yaw_rate = np.gradient(yaw, imu_stamps * 1e-9)
    nodes = {ns: NodeProcess(DOMAIN, ['-r', f'__ns:=/{ns}', '-p', f'matcher:={MATCHER}',
                                      '-p', f'prior:={prior}'])
             for ns, prior in (('wheel', 'odom'), ('gyro', 'imu'))}
    try:
        clients = {ns: OdometryClient(peer, f'/{ns}') for ns in nodes}
        odom_pub = peer.node.create_publisher(Odometry, '/wheel/wheel_odom', 100)
        imu_pub = peer.node.create_publisher(Imu, '/gyro/imu', 100)
        for ns, client in clients.items():
            assert client.wait_ready(), nodes[ns].output()
        assert peer.spin_until(lambda: odom_pub.get_subscription_count() >= 1
                               and imu_pub.get_subscription_count() >= 1, 15.0)
        sent = {'wheel': 0, 'gyro': 0}
        stale_from = len(scans) - 10

        def feed(index: int) -> None:
            horizon = scans[index].stamp_ns + 20_000_000
            if index < stale_from:  # the wheel odometry stops for the last 10 scans
                while sent['wheel'] < len(wheel) and wheel.stamps_ns[sent['wheel']] <= horizon:
                    k = sent['wheel']
                    odom_pub.publish(odometry_msg(wheel.stamps_ns[k], wheel.poses[k]))
                    sent['wheel'] += 1
            while imu_stamps[sent['gyro']] <= horizon:
                imu_pub.publish(imu_msg(imu_stamps[sent['gyro']], yaw_rate[sent['gyro']]))
                sent['gyro'] += 1

        # Warm-up at a modest pace, so that the prior history before the first scan
        # reaches the nodes even if their readers match our writers a moment late.
        # (The simulated wheel odometry starts at the first scan: it has no history.)
        warm_up = int((imu_stamps < scans[0].stamp_ns).sum())
        for k in range(warm_up):
            imu_pub.publish(imu_msg(imu_stamps[k], yaw_rate[k]))
            peer.spin_for(0.01)
        sent['gyro'] = warm_up
        for i, scan in enumerate(scans):
            feed(i)
            for ns, client in clients.items():
                reply = client.send(scan)
                error = pose_error(odometry_pose(reply), se2.relative(truth[0], truth[i]))
                assert error[0] < 0.03 and error[1] < 0.01, (ns, i, error)
        wheel_motion = wheel.motion_between(scans[0].stamp_ns, scans[stale_from].stamp_ns)
        assert pose_error(wheel_motion, se2.relative(truth[0], truth[stale_from]))[0] > 0.05
        counts = {}
        for ns in nodes:
            values, _ = latest_status(peer, f'{ns}/{STATUS}',
                                      lambda v, s: v['scans processed'] == str(len(scans)))
            counts[ns] = int(values.get('prior_missing', 0))
        assert counts['gyro'] == 0
        assert 8 <= counts['wheel'] <= 10
        assert nodes['wheel'].wait_for_output('odom prior on /wheel/wheel_odom missing or stale')
        assert 'prior odom from /wheel/wheel_odom' in nodes['wheel'].output()
    finally:
        for process in nodes.values():
            process.interrupt()


def test_every_config_file_starts_the_node_and_ctrl_c_exits_cleanly():
    files = sorted((ROOT / 'config').glob('*.yaml'))
    assert any(f.name == 'default.yaml' for f in files)
    nodes = {f: NodeProcess(unique_domain_id(), ['--params-file', str(f)]) for f in files}
    try:
        for f, process in nodes.items():
            # The start-up line names the file's matcher: the file was applied.
            document = yaml.safe_load(f.read_text())
            matcher = next(iter(document.values()))['ros__parameters'].get('matcher', 'icp')
            started = process.wait_for_output(f'laser odometry: matcher {matcher},',
                                              STARTUP_TIMEOUT)
            assert started, process.output()
    finally:
        codes = {f.name: process.interrupt() for f, process in nodes.items()}
    assert all(code == 0 for code in codes.values()), codes
    for f, process in nodes.items():
        output = process.output()
        assert 'Traceback' not in output and '[ERROR]' not in output, output
        assert 'is not a parameter of this node' not in output, output
        if not extrinsic.TF2_AVAILABLE:
            assert output.count('tf2_ros is not available') == 1
