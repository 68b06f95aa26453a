"""Offline is live: the node and the replay read params files alike and write the same bytes.

Every row of the params-file table is given to the real node (its own process, over
DDS) and to the replay; both must refuse it with the same message, or accept it with
the same warnings and the same matcher. The replay's output bag must hold, byte for
byte, the ``odom`` and ``pose`` messages the node publishes for the same scans. The
parameter service, ``--help``, namespaced and renamed nodes and the debug cloud are
checked on the running node.
"""

import re
import subprocess
import sys

from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from node_harness import (
    call, NodeProcess, odometry_pose, OdometryClient, READY_LINE, ROOT, STARTUP_TIMEOUT,
    TEST_WORLD, unique_domain_id, wait_for)
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosbags.rosbag2 import Reader
from sensor_msgs.msg import PointCloud2
import yaml

from laser_odom.core import se2
from laser_odom.core.scan.laser_scan import scan_to_points
from laser_odom.core.simulation import simulate
from laser_odom.core.simulation.sensors import sensor_model
from laser_odom.io.bag_writer import canonical_cdr, write_bag
from laser_odom.ros import extrinsic
from laser_odom.tools import replay

DOMAIN = unique_domain_id()
NODE_ERROR = 'laser_odom_node: error: '
REPLAY_ERROR = 'laser_odom_replay: error: '
REPLAY_WARNING = 'laser_odom_replay: warning: '
SCANS = 40
TYPES = {'/odom': 'nav_msgs/msg/Odometry', '/pose': 'geometry_msgs/msg/PoseStamped'}


@pytest.fixture(scope='module')
def dataset():
    """Return 4 s of the test room under a 10 Hz rotating lidar (de-skewed live and offline)."""
    data = simulate(TEST_WORLD, SCANS / 10.0, sensor_model('ld06'), seed=5)
    assert all(scan.time_increment > 0.0 for scan in data.scans)
    return data


@pytest.fixture(scope='module')
def bag(dataset, tmp_path_factory):
    """Write the scans into a ROS 2 bag for the replay."""
    path = tmp_path_factory.mktemp('same') / 'room'
    write_bag(path, dataset.scans)
    return path


PARAMS_FILES = {
    'misspelt parameter': '/**:\n  ros__parameters:\n    matcher: icp\n    max_scan_gapp: 5.0\n',
    'misspelt matcher section':
        '/**:\n  ros__parameters:\n    matcher: icp\n    nicpp:\n      max_iterations: 3\n',
    'misspelt matcher parameter':
        '/**:\n  ros__parameters:\n    matcher: icp\n    icp:\n      max_iteratons: 3\n',
    'integer for a double': '/**:\n  ros__parameters:\n    matcher: icp\n    max_scan_gap: 5\n',
    'unquoted off': '/**:\n  ros__parameters:\n    matcher: icp\n    global_search: off\n',
    'no ros__parameters': 'laser_odom:\n  matcher: icp\n',
    'another node': 'front_odom:\n  ros__parameters:\n    matcher: icp\n',
    'node name': 'laser_odom:\n  ros__parameters:\n    matcher: icp\n',
    'namespaced elsewhere': '/robot1/laser_odom:\n  ros__parameters:\n    matcher: icp\n',
    'wrong type': '/**:\n  ros__parameters:\n    matcher: icp\n    max_scan_gap: soon\n',
    'out of range': '/**:\n  ros__parameters:\n    min_inlier_ratio: 7.0\n',
    'not YAML': '/**:\n  ros__parameters:\n    matcher: [icp\n',
    'beside ros__parameters': '/**:\n  ros__parameters:\n    matcher: icp\n  extra: 1\n',
    'empty': '',
    'crossed pair': '/**:\n  ros__parameters:\n    nicp:\n      normal_neighbours: 6\n'
                    '      normal_min_neighbours: 7\n',
}
"""Each row: a params file the issue found read differently by the node and the replay."""

UNADDRESSED = ('another node', 'namespaced elsewhere', 'empty')
"""Rows none of whose sections addresses /laser_odom."""


def _node_outcome(process: NodeProcess) -> tuple:
    """Return ``(error, warnings, matcher)`` from the node's start-up output.

    The node either starts (its start-up line) or stops with an error line: whichever
    comes, however long its warm-up takes.
    """
    process.wait_for_output(READY_LINE, STARTUP_TIMEOUT)
    output = process.output()
    errors = [line[len(NODE_ERROR):] for line in output.splitlines()
              if line.startswith(NODE_ERROR)]
    warnings = [line.split(']: ', 1)[1] for line in output.splitlines()
                if line.startswith('[WARN]')]
    matcher = re.search(r'laser odometry: matcher (\w+),', output)
    return (errors[0] if errors else None, sorted(warnings),
            matcher.group(1) if matcher else None)


def _replay_outcome(bag, path, capsys) -> tuple:
    """Return ``(error, warnings, matcher)`` from the replay's output."""
    code = replay.main([str(bag), '--params-file', str(path)])
    out, err = capsys.readouterr()
    errors = [line[len(REPLAY_ERROR):] for line in err.splitlines()
              if line.startswith(REPLAY_ERROR)]
    warnings = [line[len(REPLAY_WARNING):] for line in err.splitlines()
                if line.startswith(REPLAY_WARNING)
                and line[len(REPLAY_WARNING):].startswith(('parameter ', 'params file '))]
    matcher = re.search(r'\((\w+)\): processed', out)
    assert (code == 2) == bool(errors), (code, err)
    return (errors[0] if errors else None, sorted(warnings),
            matcher.group(1) if matcher else None)


def test_node_and_replay_judge_every_params_file_alike(bag, tmp_path, capsys):
    paths = {}
    for k, (label, text) in enumerate(PARAMS_FILES.items()):
        paths[label] = tmp_path / f'file{k}.yaml'
        paths[label].write_text(text)
    nodes = {label: NodeProcess(DOMAIN, ['--params-file', str(path)])
             for label, path in paths.items()}
    try:
        live = {label: _node_outcome(process) for label, process in nodes.items()}
    finally:
        for process in nodes.values():
            process.interrupt()
    offline = {label: _replay_outcome(bag, path, capsys) for label, path in paths.items()}
    # A file that addresses another node: the node starts on its defaults and says so
    # (as ROS does); the replay refuses to run settings the user did not ask for.
    for label in UNADDRESSED:
        _, (warning,), matcher = live[label]
        assert matcher == 'nicp' and ', the node runs on its defaults for them' in warning
        assert offline[label] == (warning.replace(
            'the node runs on its defaults for them', 'so nothing would be run with it'),
            [], None), (label, offline[label])
    for label in set(PARAMS_FILES) - set(UNADDRESSED):
        assert live[label] == offline[label], (label, live[label], offline[label])
    # What each row means, so that "alike" cannot be "alike and wrong".
    expected_errors = {'no ros__parameters': 'ros__parameters', 'wrong type': 'max_scan_gap',
                       'out of range': 'min_inlier_ratio', 'not YAML': 'not valid YAML',
                       'beside ros__parameters': 'extra', 'crossed pair':
                       'nicp.normal_min_neighbours=7 must not exceed nicp.normal_neighbours=6'}
    for label, (error, warnings, matcher) in live.items():
        if label in expected_errors:
            assert expected_errors[label] in error and matcher is None, (label, error)
            continue
        assert error is None, (label, error)
        applied = label not in UNADDRESSED
        assert matcher == ('icp' if applied else 'nicp'), (label, matcher)
        assert len(warnings) == (0 if label in ('integer for a double', 'unquoted off',
                                                'node name') else 1), (label, warnings)


@pytest.mark.parametrize('remap', [['-r', '__ns:=/robot1'], ['-r', '__node:=front_odom']],
                         ids=['namespace', 'renamed'])
def test_every_config_file_applies_to_a_namespaced_or_renamed_node(remap):
    files = sorted((ROOT / 'config').glob('*.yaml'))
    nodes = {f: NodeProcess(DOMAIN, [*remap, '--params-file', str(f)]) for f in files}
    try:
        for f, process in nodes.items():
            section = next(iter(yaml.safe_load(f.read_text()).values()))['ros__parameters']
            matcher = section.get('matcher', 'nicp')
            started = process.wait_for_output(f'laser odometry: matcher {matcher},',
                                              STARTUP_TIMEOUT)
            assert started, process.output()
            assert 'no section for' not in process.output()
    finally:
        for process in nodes.values():
            process.interrupt()


def test_help_prints_usage_and_exits_without_starting():
    result = subprocess.run([sys.executable, '-m', 'laser_odom.ros.node', '--help'], cwd=ROOT,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    text = result.stdout
    for word in ('usage: laser_odom_node', 'max_scan_gap', 'global_search', 'publish_debug',
                 'odom', 'pose', '~/reset', '~/set_pose', '/diagnostics', '~/matched_scan',
                 str(ROOT / 'config'), 'default.yaml', '"/**:"'):
        assert word in text, word
    assert 'laser odometry: matcher' not in text + result.stderr


def test_help_into_a_reader_that_leaves_exits_quietly():
    """``laser_odom_node --help | head -1``: the usage was asked for, so still exit 0."""
    process = subprocess.Popen([sys.executable, '-m', 'laser_odom.ros.node', '--help'],
                               cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
    process.stdout.close()  # the reader is gone before the first line
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 0, stderr
    assert 'Traceback' not in stderr and 'BrokenPipeError' not in stderr, stderr


@pytest.fixture(scope='module')
def node(peer):
    """Start a node with the debug cloud on; yield the process and an odometry client."""
    process = NodeProcess(DOMAIN, ['-p', 'publish_debug:=true', '-p', 'matcher:=plicp'])
    client = OdometryClient(peer)
    assert client.wait_ready(), process.output()
    yield process, client
    process.interrupt()


def test_output_bag_holds_the_messages_the_node_publishes(peer, node, dataset, tmp_path):
    process, client = node
    reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    published = {'/odom': {}, '/pose': {}}

    def keep(topic: str, kind: type, data: bytes) -> None:
        # The middleware leaves garbage in the alignment padding; every field's bytes
        # are compared, the padding is zeroed as in the bag.
        stamp = deserialize_message(data, kind).header.stamp
        published[topic][stamp.sec * 10 ** 9 + stamp.nanosec] = canonical_cdr(
            bytes(data), TYPES[topic])

    for topic, kind in (('/odom', Odometry), ('/pose', PoseStamped)):
        peer.node.create_subscription(
            kind, topic, lambda data, t=topic, k=kind: keep(t, k, data), reliable, raw=True)
    for scan in dataset.scans:
        client.send(scan)
    assert peer.spin_until(lambda: all(len(v) == SCANS for v in published.values()), 15.0)

    offline = tmp_path / 'offline'
    bag = tmp_path / 'scans'
    write_bag(bag, dataset.scans)
    assert replay.main([str(bag), '--matcher', 'plicp', '--output-bag', str(offline),
                        '--quiet']) == 0
    written = {'/odom': {}, '/pose': {}}
    with Reader(offline) as reader:
        for connection, stamp_ns, data in reader.messages():
            written[connection.topic][stamp_ns] = bytes(data)
    for topic in ('/odom', '/pose'):
        assert sorted(written[topic]) == sorted(published[topic]), topic
        differing = [s for s in written[topic] if written[topic][s] != published[topic][s]]
        assert differing == [], (topic, len(differing))
    # The bytes carry what a planar odometry must say: 1e6 where it does not observe.
    last = deserialize_message(published['/odom'][max(published['/odom'])], Odometry)
    covariance = np.reshape(last.pose.covariance, (6, 6))
    assert covariance[2, 2] == covariance[3, 3] == covariance[4, 4] == 1.0e6
    assert np.reshape(last.twist.covariance, (6, 6))[0, 0] > 0.0


def test_debug_cloud_is_the_scan_moved_by_the_published_pose(peer, node, dataset):
    process, client = node
    clouds = []
    peer.node.create_subscription(PointCloud2, '/laser_odom/matched_scan', clouds.append,
                                  QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    assert peer.spin_until(
        lambda: peer.node.count_publishers('/laser_odom/matched_scan') >= 1, 15.0)
    peer.spin_for(0.5)
    scan = dataset.scans[-1]
    # The last scan again, as if the robot had stopped dead within 0.1 s (which no robot
    # does), and without sweep timing: not de-skewed, the cloud is its points as measured.
    scan = type(scan)(**{**scan.__dict__, 'stamp_ns': scan.stamp_ns + 10 ** 8,
                         'time_increment': 0.0})
    odometry = client.send(scan)
    assert peer.spin_until(lambda: any(
        c.header.stamp == odometry.header.stamp for c in clouds), 10.0)
    cloud = next(c for c in clouds if c.header.stamp == odometry.header.stamp)
    assert cloud.header.frame_id == 'odom' and cloud.point_step == 12
    xyz = np.frombuffer(bytes(cloud.data), dtype=np.float32).reshape(-1, 3)
    expected = se2.transform_points(odometry_pose(odometry), scan_to_points(scan).points)
    assert xyz.shape[0] == len(expected) and np.all(xyz[:, 2] == 0.0)
    assert np.max(np.abs(xyz[:, :2] - expected)) < 1e-4


def test_parameter_service_takes_integers_and_names_what_it_refuses(peer, node):
    parameters = AsyncParameterClient(peer.node, '/laser_odom')
    assert parameters.wait_for_services(timeout_sec=15.0)

    def set_value(name, value):
        return call(peer, parameters.set_parameters([Parameter(name, value=value)])).results[0]

    def get_value(name):
        return call(peer, parameters.get_parameters([name])).values[0]

    assert set_value('max_scan_gap', 5).successful  # ros2 param set ... max_scan_gap 5
    assert get_value('max_scan_gap').double_value == 5.0
    assert set_value('global_search', False).successful  # ros2 param set ... global_search off
    assert get_value('global_search').string_value == 'off'
    assert set_value('global_search', 'recover').successful
    result = set_value('max_scan_gapp', 5.0)
    assert not result.successful and "'max_scan_gapp'" in result.reason
    assert "'max_scan_gap'" in result.reason  # and what was probably meant
    result = set_value('max_scan_gap', 'soon')
    assert not result.successful and 'max_scan_gap must be a number' in result.reason
    if not extrinsic.TF2_AVAILABLE:
        assert get_value('publish_tf').bool_value is False  # reads back what happens
        assert set_value('publish_tf', False).successful
        result = set_value('publish_tf', True)
        assert not result.successful and 'tf2_ros' in result.reason
        assert get_value('publish_tf').bool_value is False
    assert wait_for(lambda: 'Traceback' not in node[0].output(), 0.1)


def test_replay_quiet_silences_warnings_but_not_errors(bag, tmp_path, capsys):
    typo = tmp_path / 'typo.yaml'
    typo.write_text('/**:\n  ros__parameters:\n    max_scan_gapp: 5.0\n')
    assert replay.main([str(bag), '--params-file', str(typo)]) == 0
    assert "'max_scan_gapp'" in capsys.readouterr().err
    assert replay.main([str(bag), '--params-file', str(typo), '--quiet']) == 0
    assert capsys.readouterr().err == ''
    bad = tmp_path / 'bad.yaml'
    bad.write_text('/**:\n  ros__parameters:\n    max_scan_gap: soon\n')
    assert replay.main([str(bag), '--params-file', str(bad), '--quiet']) == 2
    assert 'max_scan_gap must be a number' in capsys.readouterr().err


def test_replay_reads_the_file_for_the_node_name_it_is_given(bag, tmp_path, capsys):
    named = tmp_path / 'named.yaml'
    named.write_text('front_odom:\n  ros__parameters:\n    matcher: icp\n')
    assert replay.main([str(bag), '--params-file', str(named), '--node-name', 'front_odom',
                        '--quiet']) == 0
    assert '(icp): processed' in capsys.readouterr().out
    # Issue 39: without the name nothing in the file applies - an error, not a run on
    # the defaults that looks like one of the file's settings.
    assert replay.main([str(bag), '--params-file', str(named)]) == 2
    out, err = capsys.readouterr()
    assert out == '' and err == (
        f'laser_odom_replay: error: params file {named} has no section for /laser_odom (it '
        'has front_odom): none of its parameters apply, so nothing would be run with it - use '
        '"/**:" to address the node under any name and namespace\n')
