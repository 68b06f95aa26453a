"""The node object in-process: the TF paths and the scan callback, step by step.

tf2_ros has no pip wheels, so the TF test stands in a minimal fake with the same calls
the node makes (``Buffer.lookup_transform``, ``TransformListener``,
``TransformBroadcaster.sendTransform``, ``TransformException``) and drives the real
node object scan by scan.
"""

import math
import subprocess
import sys
import time
import types

from geometry_msgs.msg import TransformStamped
from node_harness import child_env, odometry_msg, pose_error, TEST_WORLD, unique_domain_id
import numpy as np
import pytest
from rclpy.parameter import Parameter

from laser_odom.core import se2
from laser_odom.core.scan.laser_scan import LaserMounting
from laser_odom.core.simulation import LaserModel, simulate
from laser_odom.ros import extrinsic
from laser_odom.ros.conversions import scan_to_msg, stamp_to_ns
from laser_odom.ros.node import LaserOdomNode


class FakeTransformException(Exception):
    """Stands in for tf2_ros.TransformException."""


class FakeBuffer:
    """A TF buffer holding fixed transforms keyed by (target, source)."""

    transforms: dict = {}

    def lookup_transform(self, target, source, time):
        try:
            return self.transforms[(target, source)]
        except KeyError:
            raise FakeTransformException(f'"{source}" passed to lookupTransform does not exist')


class FakeBroadcaster:
    """Records every broadcast transform."""

    sent: list = []

    def __init__(self, node):
        pass

    def sendTransform(self, transform):  # noqa: N802 (tf2_ros spelling)
        self.sent.append(transform)


@pytest.fixture
def fake_tf(monkeypatch):
    fake = types.SimpleNamespace(
        TransformException=FakeTransformException, Buffer=FakeBuffer,
        TransformListener=lambda buffer, node, spin_thread=False: None,
        TransformBroadcaster=FakeBroadcaster)
    monkeypatch.setattr(extrinsic, 'tf2_ros', fake)
    monkeypatch.setattr(extrinsic, 'TF2_AVAILABLE', True)
    FakeBuffer.transforms, FakeBroadcaster.sent = {}, []
    return fake


def test_extrinsic_from_tf_and_odom_broadcast(fake_tf, context):
    mounting = LaserMounting(-0.2, 0.15, 2.0, True)
    data = simulate(TEST_WORLD, 3.0, LaserModel(frame_id='laser'), seed=6, mounting=mounting)
    node = LaserOdomNode(context=context, parameter_overrides=[
        Parameter('use_tf_extrinsic', value=True), Parameter('matcher', value='plicp')])
    try:
        node._process(scan_to_msg(data.scans[0]), {})
        assert node.pipeline.counters['extrinsic_missing'] == 1 and not FakeBroadcaster.sent

        transform = TransformStamped()
        transform.transform.translation.x, transform.transform.translation.y = -0.2, 0.15
        transform.transform.translation.z = 0.3
        # roll pi, then yaw 2.0: q = q_z(2.0) * q_x(pi)
        q = transform.transform.rotation
        q.x, q.y, q.z, q.w = math.cos(1.0), math.sin(1.0), 0.0, 0.0
        FakeBuffer.transforms[('base_link', 'laser')] = transform

        truth = data.reference.poses
        for scan in data.scans[1:]:
            node._process(scan_to_msg(scan), {})
        applied = node.pipeline.validator.mounting
        assert applied.upside_down and applied.yaw == pytest.approx(2.0)
        error = pose_error(node.pipeline.pose, se2.relative(truth[1], truth[-1]))
        assert error[0] < 0.03 and error[1] < 0.01, error
        sent = FakeBroadcaster.sent
        assert len(sent) == len(data.scans) - 1
        assert (sent[-1].header.frame_id, sent[-1].child_frame_id) == ('odom', 'base_link')
        assert stamp_to_ns(sent[-1].header.stamp) == data.scans[-1].stamp_ns
        assert np.allclose([sent[-1].transform.translation.x, sent[-1].transform.translation.y],
                           node.pipeline.pose[:2])
    finally:
        node.destroy_node()


def test_scans_are_matched_in_the_callback_and_the_missing_ones_counted(context):
    """Each scan is published from its own callback; the ones never seen are counted.

    The callback is driven with the DDS metadata it gets: a scan received before the
    node finished the previous one waited, so the scans published in between were
    overwritten because the node was busy; otherwise they were lost on the way.
    """
    data = simulate(TEST_WORLD, 1.5, LaserModel(), seed=8)
    node = LaserOdomNode(context=context, parameter_overrides=[
        Parameter('matcher', value='plicp')])
    published = []
    node._odom_pub.publish = published.append

    def arrive(index: int, waited: bool) -> None:
        received = 1 if waited else time.time_ns()
        node._on_scan(scan_to_msg(data.scans[index]), {
            'received_timestamp': received, 'publication_sequence_number': index + 1})

    try:
        for index in range(6):  # one at a time: the scan period is learnt
            arrive(index, waited=False)
        assert len(published) == 6
        arrive(8, waited=True)  # 6 and 7 overwritten while 5 was matched
        arrive(10, waited=False)  # 9 lost on the network
        arrive(11, waited=False)
        counters = node.pipeline.counters
        assert counters['processed'] == 9 and len(published) == 9
        assert [stamp_to_ns(m.header.stamp) for m in published[-3:]] == [
            data.scans[i].stamp_ns for i in (8, 10, 11)]
        assert counters['skipped_backlog'] == 2 and counters['missed_scans'] == 1
        assert node._received == 11  # the overwritten ones did reach the node
        assert len(node._latencies) == 9
    finally:
        node.destroy_node()


def test_a_scan_waits_for_its_prior_while_the_prior_is_still_arriving(context):
    """Wheel odometry queued behind a scan is used (interpolated), not extrapolated past.

    The scan waits a turn of the executor while odometry messages keep arriving and
    its stamp is not yet covered; when none arrive it is matched with what is there,
    and a newer scan sends a waiting one on at once.
    """
    data = simulate(TEST_WORLD, 1.5, LaserModel(), seed=8)
    wheel, scans = data.odometry, data.scans
    node = LaserOdomNode(context=context, parameter_overrides=[
        Parameter('matcher', value='plicp'), Parameter('prior', value='odom')])
    sent = 0

    def odometry_until(stamp_ns: int) -> None:
        nonlocal sent
        while sent < len(wheel.stamps_ns) and wheel.stamps_ns[sent] <= stamp_ns:
            node._priors._on_odometry(odometry_msg(wheel.stamps_ns[sent], wheel.poses[sent]))
            sent += 1

    def arrive(index: int) -> None:
        node._on_scan(scan_to_msg(scans[index]), {})

    counters = node.pipeline.counters
    try:
        for index in range(4):  # covered by the odometry: matched at once
            odometry_until(scans[index].stamp_ns)
            arrive(index)
            assert counters['processed'] == index + 1 and node._waiting is None
        odometry_until(scans[4].stamp_ns - 30_000_000)
        arrive(4)  # the odometry is behind: the scan waits
        assert counters['processed'] == 4 and node._waiting is not None
        odometry_until(scans[4].stamp_ns - 10_000_000)
        node._on_prior_wait()  # still behind, but a message came: wait another turn
        assert counters['processed'] == 4
        odometry_until(scans[4].stamp_ns + 10_000_000)
        node._on_prior_wait()  # covered: matched
        assert counters['processed'] == 5 and node._waiting is None
        assert counters['prior_missing'] == 0

        arrive(5)  # behind, and no odometry comes: matched after one turn
        assert counters['processed'] == 5
        node._on_prior_wait()
        assert counters['processed'] == 6
        arrive(6)
        arrive(7)  # a newer scan: the waiting one is matched first
        assert counters['processed'] == 7
        assert node.pipeline.last_stamp_ns == scans[6].stamp_ns
        node._on_prior_wait()
        assert counters['processed'] == 8
        truth = data.reference.poses
        error = pose_error(node.pipeline.pose, se2.relative(truth[0], truth[7]))
        assert error[0] < 0.03 and error[1] < 0.01, error
    finally:
        node.destroy_node()


def test_ctrl_c_inside_a_kernel_stops_the_node_and_a_bad_scan_does_not(context, monkeypatch):
    """Ctrl-C while a numba kernel runs comes back as a SystemError caused by it.

    The node logged it as a failed scan ("[ERROR] failed to process a scan:
    SystemError('CPUDispatcher(<function gauss_newton ...>) returned a result with an
    exception set')") and spun on: test_node's Ctrl-C test failed so once, under load.
    It now stops as Ctrl-C does anywhere else; any other error of one scan is still
    logged, and the next scan matched.
    """
    from laser_odom.ros.run import interrupted

    def bad_scan(*args):
        raise ValueError('bad scan')

    def kernel_interrupted(*args):
        try:
            raise KeyboardInterrupt()
        except KeyboardInterrupt as interrupt:
            raise SystemError('returned a result with an exception set') from interrupt

    data = simulate(TEST_WORLD, 1.0, LaserModel(), seed=8)
    node = LaserOdomNode(context=context, parameter_overrides=[
        Parameter('matcher', value='plicp')])
    published, errors = [], []
    node._odom_pub.publish = published.append
    monkeypatch.setattr(node, 'get_logger', lambda: types.SimpleNamespace(
        error=errors.append, info=lambda message: None, warning=lambda message: None))

    def arrive(index: int) -> None:
        node._on_scan(scan_to_msg(data.scans[index]), {
            'received_timestamp': time.time_ns(), 'publication_sequence_number': index + 1})

    try:
        arrive(0)
        process = node.pipeline.process
        monkeypatch.setattr(node.pipeline, 'process', bad_scan)
        arrive(1)
        assert len(errors) == 1 and 'bad scan' in errors[0]
        monkeypatch.setattr(node.pipeline, 'process', kernel_interrupted)
        with pytest.raises(KeyboardInterrupt):
            arrive(2)
        assert len(errors) == 1, errors
        monkeypatch.setattr(node.pipeline, 'process', process)
        arrive(3)
        assert len(published) == 2
    finally:
        node.destroy_node()
    with pytest.raises(ValueError) as bad:
        bad_scan()
    assert not interrupted(bad.value)
    with pytest.raises(SystemError) as in_kernel:
        kernel_interrupted()
    assert interrupted(in_kernel.value)


SLOW_SIGNAL_THREAD = """
import threading
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from laser_odom.ros import run

seen = []


class Probe(Node):
    def __init__(self, params_files):
        super().__init__('teardown_probe')

    def destroy_node(self):
        seen.append(rclpy.ok())
        super().destroy_node()


def interrupted_spin(executor):
    # What rclpy's deferred signal thread does, late: shut the context down.
    context = rclpy.get_default_context().handle
    threading.Timer(0.3, context.shutdown).start()
    raise KeyboardInterrupt()


SingleThreadedExecutor.spin = interrupted_spin
code = run.run_node(['probe'], Probe, 'probe', lambda: '')
print('exit', code, 'context ok at destroy_node:', seen)
"""


def test_ctrl_c_teardown_waits_for_the_signal_thread(tmp_path):
    """The node is destroyed only once rclpy's signal thread has shut the context down.

    That thread triggers the executors' SIGINT guard conditions with no lock against
    the main thread; tearing down beside it segfaulted about one Ctrl-C in a hundred
    (exit -11, test_lifecycle in CI). Here it runs 0.3 s late, in a process of its own.
    """
    script = tmp_path / 'slow_signal_thread.py'
    script.write_text(SLOW_SIGNAL_THREAD)
    done = subprocess.run([sys.executable, str(script)], env=child_env(unique_domain_id()),
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    assert 'exit 0 context ok at destroy_node: [False]' in done.stdout, done.stdout
