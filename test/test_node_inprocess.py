"""The node object in-process: the TF paths and the latest-scan slot, step by step.

tf2_ros has no pip wheels, so the TF test stands in a minimal fake with the same calls
the node makes (``Buffer.lookup_transform``, ``TransformListener``,
``TransformBroadcaster.sendTransform``, ``TransformException``) and drives the real
node object scan by scan.
"""

import math
import types

from geometry_msgs.msg import TransformStamped
from node_harness import pose_error, TEST_WORLD, wait_for
import numpy as np
import pytest
from rclpy.parameter import Parameter

from laser_odom.core import se2
from laser_odom.core.scan import LaserMounting
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
        node.shutdown()
        node.destroy_node()


def test_busy_worker_keeps_only_the_newest_scan(context):
    """While a scan is being matched, newer scans replace each other in the slot."""
    data = simulate(TEST_WORLD, 1.5, LaserModel(), seed=8)
    node = LaserOdomNode(context=context, parameter_overrides=[
        Parameter('matcher', value='plicp')])
    msgs = [scan_to_msg(scan) for scan in data.scans]
    try:
        for i, msg in enumerate(msgs[:6]):  # one at a time: the scan period is learnt
            node._on_scan(msg)
            assert wait_for(lambda: node.pipeline.counters['processed'] == i + 1, 10.0)
        processed = node.pipeline.counters['processed']
        with node._lock:  # the worker takes the next scan, then waits for the pipeline
            node._on_scan(msgs[6])
            assert wait_for(lambda: node._slot is None, 10.0)
            for msg in (msgs[7], msgs[8], msgs[10]):  # msgs[9] is lost on the wire
                node._on_scan(msg)
        assert wait_for(lambda: node.pipeline.counters['processed'] == processed + 2, 10.0)
        assert node.pipeline.last_stamp_ns == data.scans[10].stamp_ns
        assert node.pipeline.counters['skipped_backlog'] == 2
        assert node.pipeline.counters['missed_scans'] == 1
        assert node._received == 10
    finally:
        node.shutdown()
        node.destroy_node()
