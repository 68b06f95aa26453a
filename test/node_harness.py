"""DDS test harness: the real node in its own process, a test-side rclpy peer, simulated data.

Every test module picks its own ``ROS_DOMAIN_ID`` so parallel test runs cannot talk to
each other. Waiting is always on a condition (discovery, a message with a given stamp,
a log line) with a generous deadline; nothing is asserted on elapsed time.
"""

from __future__ import annotations

import os
from pathlib import Path
import random
import signal
import subprocess
import sys
import tempfile
import time
from typing import Callable

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
import numpy as np
from rcl_interfaces.msg import Log
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, LaserScan as LaserScanMsg

from laser_odom.core import se2
from laser_odom.core.scan.laser_scan import LaserScan
from laser_odom.core.simulation import geometry as geo, World
from laser_odom.ros.conversions import ns_to_stamp, planar_pose_msg, scan_to_msg, stamp_to_ns

ROOT = Path(__file__).resolve().parents[1]

TEST_WORLD = World(
    'test_room', 'a 10 x 7.5 m room with boxes and pillars; every scan well constrained',
    geo.stack(geo.rectangle(-3.0, -2.5, 7.0, 5.0), geo.box(1.5, 1.2, 1.0, 0.6, 0.3),
              geo.pillar(4.5, -1.2, 0.25), geo.box(-2.0, 3.8, 1.2, 0.8),
              geo.box(6.0, 4.0, 0.8, 1.2, 0.5), geo.pillar(-1.8, -1.5, 0.3),
              geo.box(3.0, 4.3, 1.5, 0.5)),
    np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 2.5], [-1.0, 2.5], [-1.0, 0.0]]),
    corner_radius=0.7)
"""A compact structured room: the point-to-line matchers track it to millimetres."""


READY_LINE = 'laser odometry: matcher '
"""The node's start-up line, logged once it subscribes to scans (after its warm-up)."""

STARTUP_TIMEOUT = 300.0
"""Seconds a node may take to start: generous, a condition is waited for, not a time."""


def unique_domain_id() -> int:
    """Return a ROS domain id in 1..200 unlikely to be used by a concurrent test run.

    Under pytest-xdist each worker draws from its own share of the range, so the
    workers of one run never meet.
    """
    taken = os.environ.get('ROS_DOMAIN_ID')
    workers = max(int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1')), 1)
    worker = int(os.environ.get('PYTEST_XDIST_WORKER', 'gw0').lstrip('gw') or 0) % workers
    share = 200 // workers
    rng = random.Random(os.getpid() * 7919 + time.time_ns())
    while True:
        domain = 1 + worker * share + rng.randrange(share)
        if str(domain) != taken:
            return domain


def wait_for(predicate: Callable[[], bool], timeout: float, step: float = 0.05) -> bool:
    """Poll ``predicate`` until it holds or ``timeout`` seconds pass."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(step)
    return predicate()


def child_env(domain_id: int, **extra: str) -> dict[str, str]:
    """Return the environment of a child process on ``domain_id`` that imports this tree.

    The checkout goes first on ``PYTHONPATH``, so a child runs this code whatever is
    installed; ``extra`` adds or overrides variables.
    """
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get('PYTHONPATH', '')) if p)
    return dict(os.environ, ROS_DOMAIN_ID=str(domain_id), PYTHONPATH=path, **extra)


class NodeProcess:
    """``python -m laser_odom.ros.node --ros-args ...`` with its output in a file."""

    def __init__(self, domain_id: int, ros_args: list[str],
                 module: str = 'laser_odom.ros.node') -> None:
        """Start the node (``module``: ``laser_odom.ros.lifecycle`` for the managed one)."""
        env = child_env(domain_id, RCUTILS_COLORIZED_OUTPUT='0', PYTHONUNBUFFERED='1')
        self._log = tempfile.NamedTemporaryFile('w+', prefix='laser_odom_node_', suffix='.log')
        self._final: str | None = None
        self.process = subprocess.Popen(
            [sys.executable, '-m', module, '--ros-args', *ros_args],
            cwd=ROOT, env=env, stdout=self._log, stderr=subprocess.STDOUT)

    def output(self) -> str:
        """Return everything the node printed so far."""
        if self._final is not None:
            return self._final
        with open(self._log.name) as log:
            return log.read()

    def wait_for_output(self, text: str, timeout: float = 30.0) -> bool:
        """Wait until ``text`` appears in the node's output (or the node exits)."""
        return wait_for(lambda: text in self.output() or self.process.poll() is not None,
                        timeout) and text in self.output()

    def wait_started(self, timeout: float = STARTUP_TIMEOUT) -> None:
        """Wait until the node is ready for scans: its start-up line comes after its warm-up.

        A node compiles or loads its kernels before it subscribes to scans, which takes
        from a second to minutes on a busy machine: tests that need a warm node wait
        for this, never for a fixed time.
        """
        assert self.wait_for_output(READY_LINE, timeout), self.output()

    def interrupt(self, timeout: float = 20.0) -> int:
        """Send SIGINT (Ctrl-C) and return the exit code."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        try:
            return self.process.wait(timeout)
        finally:
            self.close()

    def close(self) -> None:
        """Kill the process if it still runs, and drop the log."""
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait(10)
        if self._final is None:
            self._final = self.output()
            self._log.close()


class Peer:
    """A test-side rclpy node in its own context on the test's domain."""

    def __init__(self, domain_id: int) -> None:
        """Initialise a private context (no signal handlers: pytest keeps Ctrl-C)."""
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node('laser_odom_test_peer', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.diagnostics: list[tuple[float, DiagnosticArray]] = []
        self.node.create_subscription(
            DiagnosticArray, '/diagnostics',
            lambda msg: self.diagnostics.append((time.monotonic(), msg)), 100)

    def spin_until(self, predicate: Callable[[], bool], timeout: float) -> bool:
        """Process callbacks until ``predicate`` holds or ``timeout`` seconds pass."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if predicate():
                return True
            self.executor.spin_once(timeout_sec=0.02)
        return predicate()

    def spin_for(self, seconds: float) -> None:
        """Process callbacks for a while (to let messages arrive, never as an assertion)."""
        self.spin_until(lambda: False, seconds)

    def statuses(self, name: str) -> list[tuple[float, dict[str, str], object]]:
        """Return ``(receive time, values, status)`` of every diagnostics status ``name``."""
        return [(t, {kv.key: kv.value for kv in s.values}, s)
                for t, msg in self.diagnostics for s in msg.status if s.name == name]

    def close(self) -> None:
        """Destroy the node and shut the context down."""
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


class SimClock:
    """``/clock`` from the test's peer: 0.1 s of sim time per tick, from ``start_ns``."""

    STEP_NS = 100_000_000

    def __init__(self, peer: Peer, start_ns: int) -> None:
        """Create the ``/clock`` publisher on ``peer`` (nothing is sent before a tick)."""
        self.peer, self.start_ns, self.ticks = peer, start_ns, 0
        self._publisher = peer.node.create_publisher(Clock, '/clock', 10)
        self._timer = None

    @property
    def now_ns(self) -> int:
        """Return the last sim time sent."""
        return self.start_ns + self.ticks * self.STEP_NS

    def tick(self) -> None:
        """Advance the clock by one step and send it."""
        self.ticks += 1
        self._publisher.publish(Clock(clock=ns_to_stamp(self.now_ns)))

    def run(self) -> None:
        """Tick every 0.1 s of wall time while the peer spins."""
        self._timer = self.peer.node.create_timer(self.STEP_NS / 1e9, self.tick)

    def stop(self) -> None:
        """Stop ticking."""
        if self._timer is not None:
            self.peer.node.destroy_timer(self._timer)
            self._timer = None


class OdometryClient:
    """Publishes scans to one node instance and collects its odometry and pose."""

    def __init__(self, peer: Peer, namespace: str = '', node_name: str = 'laser_odom') -> None:
        """Create the publishers and subscriptions of node ``node_name`` in ``namespace``."""
        self.peer = peer
        self.ns = namespace.rstrip('/')
        node = peer.node
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.scan_pub = node.create_publisher(LaserScanMsg, f'{self.ns}/scan', 10)
        self.odom: dict[int, list[Odometry]] = {}
        self.pose: dict[int, list[PoseStamped]] = {}
        self.order: list[int] = []
        self._outputs = (
            node.create_subscription(Odometry, f'{self.ns}/odom', self._on_odom, reliable),
            node.create_subscription(PoseStamped, f'{self.ns}/pose', self._on_pose, reliable))
        # Created after the outputs, on purpose: see wait_ready.
        self._logger_name = '.'.join(filter(None, (*self.ns.strip('/').split('/'), node_name)))
        self._node_heard = False
        rosout = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(Log, '/rosout', self._on_rosout, rosout)

    def _on_odom(self, msg: Odometry) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        self.odom.setdefault(stamp, []).append(msg)
        self.order.append(stamp)

    def _on_pose(self, msg: PoseStamped) -> None:
        self.pose.setdefault(stamp_to_ns(msg.header.stamp), []).append(msg)

    def _on_rosout(self, msg: Log) -> None:
        if msg.name == self._logger_name:
            self._node_heard = True

    def wait_ready(self, timeout: float = STARTUP_TIMEOUT, heard: float = 10.0) -> bool:
        """Wait until the node's scan subscription and output publishers are matched.

        The node subscribes once its kernels are loaded, which may take long on a busy
        machine: the deadline is generous, the wait ends as soon as it is there. The
        outputs count once this client's own subscriptions are matched to them, not
        just seen in the graph: an odometry published before that is lost, and the
        scan sent again has the same stamp, which the node drops.

        That is this side's match only. The node's writers match our readers when the
        node has read our readers' discovery announcements, which may come later on a
        busy machine (a CI run lost the first scan's odometry so, with every match
        here in place). Those announcements arrive in order, so the node's log on
        ``/rosout`` (kept for late readers), reaching our reader made after the
        outputs' readers, shows that it knows them: that is waited for too, at most
        ``heard`` seconds (the kept log lines expire after 10 s).
        """
        matched = self.peer.spin_until(
            lambda: (self.scan_pub.get_subscription_count() >= 1
                     and all(sub.get_publisher_count() >= 1 for sub in self._outputs)),
            timeout)
        if matched:
            self.peer.spin_until(lambda: self._node_heard, heard)
        return matched

    def has_output(self, stamp_ns: int) -> bool:
        """Tell whether odometry and pose for a stamp have arrived."""
        return stamp_ns in self.odom and stamp_ns in self.pose

    def send(self, scan: LaserScan, timeout: float = 15.0,
             before: Callable[[], None] | None = None) -> Odometry:
        """Publish a scan and wait for its odometry (re-sent if lost on the wire)."""
        msg = scan_to_msg(scan)
        for _ in range(3):
            if before is not None:
                before()
            self.scan_pub.publish(msg)
            if self.peer.spin_until(lambda: self.has_output(scan.stamp_ns), timeout / 3):
                return self.odom[scan.stamp_ns][-1]
        raise AssertionError(f'no odometry for the scan stamped {scan.stamp_ns}')


def odometry_pose(msg: Odometry | PoseStamped) -> np.ndarray:
    """Return ``[x, y, yaw]`` of an Odometry or PoseStamped message."""
    pose = msg.pose.pose if isinstance(msg, Odometry) else msg.pose
    q = pose.orientation
    return se2.pose(pose.position.x, pose.position.y,
                    se2.quaternion_to_yaw(q.x, q.y, q.z, q.w))


def pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Return the translation [m] and absolute yaw [rad] error of a pose."""
    delta = se2.relative(truth, estimate)
    return float(np.hypot(delta[0], delta[1])), abs(float(delta[2]))


def call(peer: Peer, future: Future, timeout: float = 15.0):
    """Spin until a service future completes and return its result."""
    assert peer.spin_until(future.done, timeout), 'service call timed out'
    return future.result()


def latest_status(peer: Peer, name: str, predicate, timeout: float = 10.0):
    """Wait for a diagnostics status of ``name`` whose values satisfy ``predicate``."""
    found = []

    def check() -> bool:
        found[:] = [(v, s) for _, v, s in peer.statuses(name) if predicate(v, s)]
        return bool(found)

    assert peer.spin_until(check, timeout), peer.statuses(name)[-1:]
    return found[-1]


def odometry_msg(stamp_ns: int, pose: np.ndarray) -> Odometry:
    """Return a wheel odometry message."""
    msg = Odometry()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id, msg.child_frame_id = 'odom_wheel', 'base_link'
    msg.pose.pose = planar_pose_msg(pose)
    return msg


def imu_msg(stamp_ns: int, yaw_rate: float) -> Imu:
    """Return an IMU message with a yaw rate and no orientation."""
    msg = Imu()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.orientation_covariance[0] = -1.0  # no orientation: integrate the yaw rate
    msg.angular_velocity.z = float(yaw_rate)
    return msg
