"""On a real robot's stack (issue 39): beside robot_localization, the local map, the reference.

One node over DDS runs as docs/robot_localization.md sets it up - its ``odom`` and
``pose`` remapped under ``laser_odom/``, no TF broadcast - with ``reference:
local_map`` and ``publish_debug``, fed a simulated run of the test room. Checked:

- the robot_localization examples (``config/robot_localization/*.yaml``) against what
  the node publishes: every variable an example fuses from the node carries a finite,
  positive covariance that is neither the old 1e-6 placeholder nor too confident for
  the truth; the frames and the topic are the node's;
- the first message's twist covariance says "unknown" (nothing was matched yet);
- ``~/local_map``: in ``odom_frame``, at most once per second of scan time, its points
  on the simulated walls;
- the start-up line, ``/diagnostics`` and ``laser_odom_ctl status`` name the reference,
  for ``local_map`` here and ``scan`` on a second node.
"""

from pathlib import Path
import re

from node_harness import (
    latest_status, NodeProcess, OdometryClient, ROOT, TEST_WORLD, unique_domain_id)
import numpy as np
import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
import yaml

from laser_odom.core import se2
from laser_odom.core.configuration.node import NodeConfig
from laser_odom.core.pipeline.estimate import UNKNOWN_TWIST_VARIANCE
from laser_odom.core.simulation import geometry as geo, LaserModel, simulate
from laser_odom.io.params_file import parse_params_file, section_warnings
from laser_odom.ros.conversions import stamp_to_ns
from laser_odom.tools.ctl import main as ctl_main

DOMAIN = unique_domain_id()
MATCHER = 'plicp'
NAMESPACE = '/laser_odom'
"""The docs' remapping: laser_odom/odom and laser_odom/pose, clear of the wheels' odom."""
STATUS = 'laser_odom: odometry'
EKF_DIR = ROOT / 'config' / 'robot_localization'
EKF_FILES = sorted(EKF_DIR.glob('*.yaml'))
DOC = ROOT / 'docs' / 'robot_localization.md'
SCANS = 45
"""4.4 s of scans at 10 Hz: room for four or five maps at 1 Hz."""
STATE = ('x', 'y', 'z', 'roll', 'pitch', 'yaw', 'vx', 'vy', 'vz', 'vroll', 'vpitch', 'vyaw',
         'ax', 'ay', 'az')
"""robot_localization's state order, that of every ``<input>_config`` vector."""


@pytest.fixture(scope='module')
def dataset():
    """Return 6 s of the test room."""
    return simulate(TEST_WORLD, 6.0, LaserModel(), seed=5)


@pytest.fixture(scope='module')
def map_node(peer):
    """Start the node as docs/robot_localization.md does, with the local map on."""
    process = NodeProcess(DOMAIN, [
        '-p', f'matcher:={MATCHER}', '-p', 'reference:=local_map', '-p', 'publish_debug:=true',
        '-p', 'publish_tf:=false', '-p', f'{MATCHER}.covariance_heading_walk:=0.0',
        '-r', f'scan:={NAMESPACE}/scan', '-r', 'odom:=laser_odom/odom',
        '-r', 'pose:=laser_odom/pose'])
    clouds: list[PointCloud2] = []
    peer.node.create_subscription(
        PointCloud2, f'{NAMESPACE}/local_map', clouds.append,
        QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    client = OdometryClient(peer, NAMESPACE)
    assert client.wait_ready(), process.output()
    # The map's publisher comes up with the others; waited for (not asserted: the map's
    # own test says whether maps came) so that the first map is not missed.
    peer.spin_until(lambda: peer.node.count_publishers(f'{NAMESPACE}/local_map') > 0, 30.0)
    yield process, client, clouds
    process.interrupt()


@pytest.fixture(scope='module')
def run(map_node, dataset):
    """Send the scans one at a time; return the replies in order and the maps received."""
    process, client, clouds = map_node
    replies = [client.send(scan) for scan in dataset.scans[:SCANS]]
    client.peer.spin_until(lambda: False, 1.0)  # the last map, if one is on its way
    return replies, clouds


def ekf_parameters(path: Path) -> dict:
    document = yaml.safe_load(path.read_text())
    assert set(document) == {'ekf_filter_node'}, 'ekf_node names itself ekf_filter_node'
    return document['ekf_filter_node']['ros__parameters']


def laser_inputs(parameters: dict) -> list[str]:
    """Return the odomN inputs of an EKF example that read the node's odometry."""
    return [name for name, topic in parameters.items()
            if re.fullmatch(r'odom\d+', name) and f'/{topic}' == f'{NAMESPACE}/odom']


def fused_variances(msg, fused: list[str]) -> dict[str, float]:
    """Return the published variance of each fused state variable (pose, then twist)."""
    pose = np.asarray(msg.pose.covariance).reshape(6, 6)
    twist = np.asarray(msg.twist.covariance).reshape(6, 6)
    return {name: float(pose[k, k] if k < 6 else twist[k - 6, k - 6])
            for k, name in enumerate(STATE) if name in fused}


# --- the robot_localization examples ---------------------------------------------------

def test_ekf_examples_are_shipped_apart_from_the_node_parameter_files():
    """They are installed, and no tool takes them for a laser_odom parameter file."""
    assert [p.name for p in EKF_FILES] == ['ekf_differential.yaml', 'ekf_twist.yaml']
    assert not list((ROOT / 'config').glob('ekf*.yaml'))  # not among config/*.yaml
    setup = (ROOT / 'setup.py').read_text()
    assert "glob('config/robot_localization/*.yaml')" in setup
    for path in EKF_FILES:
        warnings = section_warnings([parse_params_file(path)], '/laser_odom')
        assert warnings and 'ekf_filter_node' in warnings[0], warnings


@pytest.mark.parametrize('path', EKF_FILES, ids=lambda p: p.stem)
def test_ekf_example_frames_and_topic_are_the_nodes(path, run):
    replies, _ = run
    parameters = ekf_parameters(path)
    node = NodeConfig()
    assert parameters['two_d_mode'] is True
    assert parameters['odom_frame'] == parameters['world_frame'] == node.odom_frame
    assert parameters['base_link_frame'] == node.base_frame
    assert {(r.header.frame_id, r.child_frame_id) for r in replies} == {
        (node.odom_frame, node.base_frame)}
    assert parameters['publish_tf'] is True  # the EKF broadcasts; the node must not
    inputs = laser_inputs(parameters)
    assert len(inputs) == 1, inputs
    differential = parameters[f'{inputs[0]}_differential']
    assert differential is (path.stem == 'ekf_differential')
    # The docs start the node with this very topic, and TF off.
    text = DOC.read_text()
    assert f'odom_topic:={parameters[inputs[0]]}' in text and 'publish_tf:=false' in text
    assert f'config/robot_localization/{path.name}' in text


@pytest.mark.parametrize('path', EKF_FILES, ids=lambda p: p.stem)
def test_what_each_example_fuses_has_an_honest_covariance(path, run, dataset):
    """Finite, positive, not the 1e-6 placeholder, and not overconfident for the truth.

    A differential input's first message is only the reference of the next one (the
    EKF turns pairs of poses into velocities), so it is not fused: the pose there is
    the origin of odom, exactly known. The twist before the first match is unknown.
    """
    replies, _ = run
    parameters = ekf_parameters(path)
    name = laser_inputs(parameters)[0]
    fused = [s for s, on in zip(STATE, parameters[f'{name}_config']) if on]
    assert len(parameters[f'{name}_config']) == len(STATE) and fused
    assert set(fused) <= {'x', 'y', 'yaw', 'vx', 'vy', 'vyaw'}  # what a 2D odometry measures
    differential = parameters[f'{name}_differential']
    used = replies[1:] if differential else replies
    variances = np.array([list(fused_variances(r, fused).values()) for r in used])
    assert np.all(np.isfinite(variances)) and np.all(variances > 0.0)
    # A placeholder is the same 1e-6 in every message; an honest variance grows and
    # may pass through it (plicp against the map here came within 0.1 % of it once).
    assert not np.any(np.all(np.isclose(variances, 1e-6, rtol=1e-3), axis=0)), (
        'placeholder covariance')
    assert np.all(variances <= UNKNOWN_TWIST_VARIANCE)
    # Against the truth: what the EKF is told is not overconfident (normalised squared
    # errors: about 1 when honest; a placeholder 1e-6 gives thousands).
    truth = dataset.reference.poses
    errors = []
    for k, reply in enumerate(replies[1:], start=1):
        dt = (dataset.scans[k].stamp_ns - dataset.scans[k - 1].stamp_ns) * 1e-9
        true_twist = se2.relative(truth[k - 1], truth[k]) / dt
        true_pose = se2.relative(truth[0], truth[k])
        measured = {'x': reply.pose.pose.position.x, 'y': reply.pose.pose.position.y,
                    'yaw': _yaw(reply), 'vx': reply.twist.twist.linear.x,
                    'vy': reply.twist.twist.linear.y, 'vyaw': reply.twist.twist.angular.z}
        expected = dict(zip(('x', 'y', 'yaw'), true_pose)) | dict(
            zip(('vx', 'vy', 'vyaw'), true_twist))
        variance = fused_variances(reply, fused)
        errors.append([(measured[s] - expected[s]) ** 2 / variance[s] for s in fused])
    normalised = np.mean(errors, axis=0)
    print(path.stem, dict(zip(fused, np.round(normalised, 2))))
    assert np.all(normalised < 5.0), dict(zip(fused, normalised))


def test_differential_fusion_gives_the_velocities_too_little_variance(run, dataset):
    """What docs/robot_localization.md warns of, on this run.

    robot_localization differentiates consecutive poses into a velocity whose
    covariance is ``(P_k + P_{k-1}) * dt`` of the integrated pose covariances
    (``preparePose``): early in a run, and against a local map throughout, far below
    the velocity's real error.
    """
    replies, _ = run
    truth = dataset.reference.poses
    normalised = []
    for k in range(2, len(replies)):
        dt = (dataset.scans[k].stamp_ns - dataset.scans[k - 1].stamp_ns) * 1e-9
        previous, current = (_pose(replies[k - 1]), _pose(replies[k]))
        velocity = se2.relative(previous, current) / dt
        true_velocity = se2.relative(truth[k - 1], truth[k]) / dt
        variance = (_pose_variance(replies[k]) + _pose_variance(replies[k - 1])) * dt
        normalised.append((velocity - true_velocity) ** 2 / variance)
    mean = np.mean(normalised, axis=0)
    print('robot_localization differential', np.round(mean, 1))
    assert np.all(mean > 20.0), mean


def _pose(msg) -> np.ndarray:
    p = msg.pose.pose.position
    return se2.pose(p.x, p.y, _yaw(msg))


def _pose_variance(msg) -> np.ndarray:
    return np.diag(np.asarray(msg.pose.covariance).reshape(6, 6))[[0, 1, 5]]


def _yaw(msg) -> float:
    q = msg.pose.pose.orientation
    return se2.quaternion_to_yaw(q.x, q.y, q.z, q.w)


def test_first_message_says_the_twist_is_unknown(run):
    """Before the first match: zero twist, variance 1e3 on vx, vy, vyaw (not 1e-6)."""
    replies, _ = run
    first = replies[0]
    twist = np.asarray(first.twist.covariance).reshape(6, 6)
    np.testing.assert_array_equal(np.diag(twist)[[0, 1, 5]], [UNKNOWN_TWIST_VARIANCE] * 3)
    assert (first.twist.twist.linear.x, first.twist.twist.angular.z) == (0.0, 0.0)
    pose = np.asarray(first.pose.covariance).reshape(6, 6)
    np.testing.assert_array_equal(np.diag(pose)[[0, 1, 5]], [0.0, 0.0, 0.0])  # the origin
    second = np.asarray(replies[1].twist.covariance).reshape(6, 6)
    assert np.all(np.diag(second)[[0, 1, 5]] < 1e-2)  # measured from here on


# --- ~/local_map ---------------------------------------------------------------------------

def test_local_map_arrives_in_odom_at_most_once_a_second_on_the_walls(run, dataset):
    replies, clouds = run
    assert len(clouds) >= 3, len(clouds)
    stamps = np.array([stamp_to_ns(c.header.stamp) for c in clouds])
    scan_stamps = {s.stamp_ns for s in dataset.scans[:SCANS]}
    assert set(stamps) <= scan_stamps  # each map goes out with a scan's stamp
    assert np.all(np.diff(stamps) >= 1_000_000_000), np.diff(stamps)
    span = (max(scan_stamps) - min(scan_stamps)) * 1e-9
    assert len(clouds) <= int(span) + 1
    truth = dataset.reference.poses
    for cloud in clouds:
        assert cloud.header.frame_id == NodeConfig().odom_frame
        assert [f.name for f in cloud.fields] == ['x', 'y', 'z', 'intensity']
        points = np.frombuffer(bytes(cloud.data), dtype=np.float32).reshape(-1, 4)
        assert len(points) == cloud.width > 100
        world = se2.transform_points(truth[0], points[:, :2].astype(float))
        distance = geo.distance_to_segments(world, TEST_WORLD.segments)
        assert np.median(distance) < 0.02 and np.percentile(distance, 95) < 0.05, (
            np.median(distance), np.percentile(distance, 95))
        assert np.all(points[:, 3] > 0.0)  # cell weights
    # The map grows as the robot drives on: the last one covers more walls.
    assert clouds[-1].width > clouds[0].width


def test_node_help_names_the_local_map():
    from laser_odom.ros.usage import usage
    line = next(line for line in usage().splitlines() if '~/local_map' in line)
    assert 'sensor_msgs/PointCloud2' in line


# --- the reference, named -----------------------------------------------------------------

def test_start_up_line_names_the_reference(map_node, run):
    process, _, _ = map_node
    assert f'laser odometry: matcher {MATCHER}, reference local_map, prior' in (
        process.output())


def test_diagnostics_name_the_reference(peer, run):
    values, _ = latest_status(peer, STATUS, lambda v, s: 'reference' in v, 15.0)
    assert values['reference'] == 'local_map' and values['matcher'] == MATCHER


def test_ctl_status_names_the_reference(run, monkeypatch, capsys):
    monkeypatch.setenv('ROS_DOMAIN_ID', str(DOMAIN))
    assert ctl_main(['--node-name', 'laser_odom', 'status']) == 0
    lines = capsys.readouterr().out.splitlines()
    assert '  reference: local_map' in lines, lines


def test_scan_reference_is_named_and_sends_no_map(peer, dataset, monkeypatch, capsys):
    """The default reference is said too; without a map, ~/local_map stays silent."""
    namespace = '/scan_ref'
    process = NodeProcess(DOMAIN, ['-r', f'__ns:={namespace}', '-p', f'matcher:={MATCHER}',
                                   '-p', 'publish_debug:=true', '-p', 'publish_tf:=false'])
    clouds: list[PointCloud2] = []
    peer.node.create_subscription(PointCloud2, f'{namespace}/laser_odom/local_map',
                                  clouds.append, 10)
    try:
        client = OdometryClient(peer, namespace)
        assert client.wait_ready(), process.output()
        for scan in dataset.scans[:15]:
            client.send(scan)
        assert f'laser odometry: matcher {MATCHER}, reference scan, prior' in process.output()
        values, _ = latest_status(peer, f'{namespace[1:]}/laser_odom: odometry',
                                  lambda v, s: v.get('scans processed') == '15', 15.0)
        assert values['reference'] == 'scan'
        monkeypatch.setenv('ROS_DOMAIN_ID', str(DOMAIN))
        assert ctl_main(['--namespace', namespace, 'status']) == 0
        assert '  reference: scan' in capsys.readouterr().out.splitlines()
        assert clouds == []
    finally:
        process.interrupt()
