"""A storm of malformed scans over DDS: the node stays alive and answers good scans."""

from node_harness import NodeProcess, odometry_pose, OdometryClient, Peer, unique_domain_id
import numpy as np
import pytest
from test_robustness import malformed_scan

from laser_odom.core.simulation import get_world, LaserModel, render_scan
from laser_odom.ros.conversions import scan_to_msg

DOMAIN = unique_domain_id()
STORM = 2000


@pytest.fixture(scope='module')
def node_and_client():
    """Start the node with its defaults and a test peer on a private domain."""
    peer = Peer(DOMAIN)
    process = NodeProcess(DOMAIN, [])
    client = OdometryClient(peer)
    assert client.wait_ready(), process.output()
    yield process, client
    process.interrupt()
    peer.close()


def test_malformed_storm_does_not_stop_the_node(node_and_client):
    process, client = node_and_client
    rng = np.random.default_rng(42)
    stamp = 1_000_000_000
    for _ in range(STORM):
        stamp += int(rng.integers(1, 50_000_000))
        client.scan_pub.publish(scan_to_msg(malformed_scan(rng, stamp)))
        client.peer.executor.spin_once(timeout_sec=0.0)
    client.peer.spin_for(1.0)
    assert process.process.poll() is None, process.output()
    # Outputs produced during the storm (scans that happened to be usable) are finite.
    for replies in client.odom.values():
        for msg in replies:
            assert np.all(np.isfinite(odometry_pose(msg)))
            assert np.all(np.isfinite(msg.pose.covariance))
    # The next good scans are answered with finite odometry.
    poses = get_world('office').path.poses_at(np.array([5.0, 5.1]))
    laser_rng = np.random.default_rng(1)
    for k, pose in enumerate(poses):
        scan = render_scan('office', pose, LaserModel(), laser_rng,
                           stamp + (k + 1) * 1_000_000_000)
        # The node may still be matching the storm's last usable scan (up to a few
        # seconds for 2000 random beams with the global search, more on a busy machine).
        odometry = client.send(scan, timeout=60.0 if k == 0 else 15.0)
        assert np.all(np.isfinite(odometry_pose(odometry)))
        assert np.all(np.isfinite(odometry.pose.covariance))
        assert np.all(np.isfinite(odometry.twist.covariance))
    assert process.process.poll() is None
    assert 'Traceback' not in process.output()
