"""``laser_odom_replay --live`` against a real ``laser_odom_node`` over DDS."""

import os
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

from laser_odom.io.tum import read_tum
from laser_odom.tools import replay, simulate

pytest.importorskip('rclpy')

ROOT = Path(__file__).resolve().parents[1]


def test_live_replay_matches_in_process_replay(tmp_path, capsys):
    bag = tmp_path / 'sim'
    assert simulate.main([str(bag), '--duration', '6', '--seed', '5']) == 0
    offline = tmp_path / 'offline.tum'
    assert replay.main([str(bag), '--tum', str(offline), '--quiet']) == 0
    capsys.readouterr()

    # A domain and a namespace of our own, so concurrent tests cannot cross-talk.
    namespace = f'/replay_live_{os.getpid()}'
    env = dict(os.environ, ROS_DOMAIN_ID=str(20 + os.getpid() % 70),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get('PYTHONPATH', ''))
    node = subprocess.Popen(
        [sys.executable, '-m', 'laser_odom.ros.node', '--ros-args', '-r', f'__ns:={namespace}'],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        live = tmp_path / 'live.tum'
        result = subprocess.run(
            [sys.executable, '-m', 'laser_odom.tools.replay', str(bag), '--live', '--quiet',
             '--tum', str(live), '--scan-topic-out', f'{namespace}/scan',
             '--odom-topic-in', f'{namespace}/odom', '--node-name',
             f'{namespace[1:]}/laser_odom'],
            cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    finally:
        node.terminate()
        try:
            node.wait(timeout=10)
        except subprocess.TimeoutExpired:
            node.kill()
            node.wait()
    assert result.returncode == 0, result.stderr + node.stdout.read()
    assert 'odometry received for 60, failed (rejected) 0' in result.stdout
    assert 'no answer 0' in result.stdout
    a, b = read_tum(live), read_tum(offline)
    # The node runs the same pipeline on the same scans: the same trajectory.
    np.testing.assert_array_equal(a.stamps_ns, b.stamps_ns)
    np.testing.assert_allclose(a.poses, b.poses, atol=1e-9)
