"""The ``laser_odom`` node: laser scans in, odometry of the robot base out.

Subscribes ``scan`` (``sensor_msgs/LaserScan``, sensor-data QoS, depth 1) and publishes
``odom`` (``nav_msgs/Odometry``) and ``pose`` (``geometry_msgs/PoseStamped``) stamped
with the scan's own stamp, plus ``odom_frame -> base_frame`` on TF when tf2_ros is
available. The odometry is :class:`laser_odom.core.pipeline.odometry.OdometryPipeline`, the
object the replay harness drives offline.

Each scan is matched in the subscription callback itself, so the result is published
without a hand-over to another thread. The node never queues scans: the subscription
keeps only the newest one (depth 1), so when matching is slower than the scanner the
newest scan is matched against the last processed one; the scans in between are
counted on ``/diagnostics`` as not processed because the node was busy, or as dropped
before reaching the node when they were lost before (see :class:`.ScanGapCounter`).
With an external prior, a scan that its wheel odometry or IMU has not reached yet waits
while their messages keep arriving, so that the prior is interpolated as offline.

``~/reset`` (``std_srvs/Trigger``) and ``~/set_pose``
(``geometry_msgs/PoseWithCovarianceStamped``) restart the integration; health goes to
``/diagnostics`` once a second; parameters are live (see :mod:`.live`). With
``publish_debug`` the matched scan goes out on ``~/matched_scan`` in the odom frame,
and with ``reference: local_map`` the map too, on ``~/local_map`` (see :mod:`.map_cloud`).
"""

from __future__ import annotations

from collections import deque
import sys
import threading
import time
from typing import Any, NamedTuple, Sequence

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data, QoSProfile
from sensor_msgs.msg import LaserScan as LaserScanMsg, PointCloud2
from std_srvs.srv import Trigger

from laser_odom.core.events import EventLog
from laser_odom.core.pipeline.estimate import OdometryEstimate
from laser_odom.core.pipeline.odometry import OdometryPipeline
from laser_odom.core.pipeline.warmup import warm_up
from laser_odom.io.params_file import ParamsFile
from laser_odom.ros import extrinsic
from laser_odom.ros.conversions import (
    initial_pose_from_msg, matched_cloud_msg, published_messages, scan_from_msg, stamp_to_ns)
from laser_odom.ros.diagnostics import (
    BUSY, DiagnosticsReporter, ScanGapCounter, Snapshot)
from laser_odom.ros.extrinsic import TfInterface
from laser_odom.ros.live import LiveParameters
from laser_odom.ros.map_cloud import MapCloud
from laser_odom.ros.priors import PriorInputs
from laser_odom.ros.run import interrupted, run_node
from laser_odom.ros.sim_time import ClockWatch
from laser_odom.ros.usage import usage

SCAN_QOS = QoSProfile(
    history=qos_profile_sensor_data.history, depth=1,
    reliability=qos_profile_sensor_data.reliability,
    durability=qos_profile_sensor_data.durability)
"""Sensor-data QoS keeping only the newest scan: a slow node must not build a queue."""

DIAGNOSTICS_PERIOD = 1.0
"""Seconds between two diagnostics reports."""

LATENCY_WINDOW = 1000
"""Recent receipt-to-publish latencies kept for /diagnostics."""

WARM_UP_NOTE_SECONDS = 2.0
"""A start whose kernel warm-up took longer than this says so, even if it compiled nothing."""


class WaitingScan(NamedTuple):
    """A received scan waiting for its prior (see :meth:`LaserOdomNode._on_prior_wait`)."""

    msg: LaserScanMsg
    skipped: dict[str, int]
    received: float
    """When it was received (monotonic clock [s]), for the receipt-to-publish latency."""
    arrivals: int
    """Prior messages received when it last checked (-1: not yet checked)."""


class LaserOdomNode(Node):
    """Scan-to-scan laser odometry as a ROS 2 node (node name ``laser_odom``)."""

    def __init__(self, params_files: Sequence[ParamsFile] = (), **kwargs) -> None:
        """Declare parameters, build the pipeline and subscribe.

        ``params_files`` are the parsed files given with ``--params-file`` (to warn when
        none of a file's sections addresses this node). Raises :class:`.live.StartupError`
        (after destroying the node) when the parameters are invalid, e.g. an unknown
        ``matcher``.
        """
        super().__init__('laser_odom', **kwargs)
        try:
            self._setup(params_files)
        except BaseException:
            self.destroy_node()
            raise

    def _setup(self, params_files: Sequence[ParamsFile]) -> None:
        """Create everything the node runs with."""
        self._declare(params_files)
        self._build()
        self.params.start()
        self._log_startup()

    def _declare(self, params_files: Sequence[ParamsFile]) -> None:
        """Judge the given parameter values and declare every parameter."""
        self._lock = threading.RLock()
        self.params = LiveParameters(self, self._on_settings, params_files,
                                     extrinsic.TF2_AVAILABLE)

    def _build(self) -> None:
        """Create the pipeline and the node's topics, services and timer from the parameters.

        The plain node does it as it starts; the managed node
        (:mod:`laser_odom.ros.lifecycle`) on each configure, with the values set by then.
        """
        settings = self.params.settings
        self._tf = TfInterface(self, settings.node.base_frame, settings.node.use_tf_extrinsic)
        self.pipeline = OdometryPipeline(
            self.params.pipeline_config(), events=EventLog(self.get_logger().warning))
        self._priors = PriorInputs(self, settings.priors)
        self._priors.configure(settings.pipeline.motion.prior, settings.priors)
        self._odom_pub = self.create_publisher(Odometry, 'odom', 10)
        self._pose_pub = self.create_publisher(PoseStamped, 'pose', 10)
        self._cloud_pub = self.create_publisher(PointCloud2, '~/matched_scan', 10)
        self._map_cloud = MapCloud(self)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._latencies: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self._gaps = ScanGapCounter()
        self._received = 0
        self._busy_until_ns = 0
        self._waiting: WaitingScan | None = None
        self._next_turn = self.create_guard_condition(self._on_prior_wait)
        self._warm_up(settings.pipeline.matcher)
        self._scan_sub = self.create_subscription(
            LaserScanMsg, 'scan', self._on_scan, SCAN_QOS)
        self.create_service(Trigger, '~/reset', self._on_reset)
        self.create_subscription(
            PoseWithCovarianceStamped, '~/set_pose', self._on_set_pose, 10)
        self._reporter = DiagnosticsReporter(
            f'{self.get_fully_qualified_name().lstrip("/")}: odometry',
            settings.node.base_frame, time.monotonic())
        self.create_timer(DIAGNOSTICS_PERIOD, self._publish_diagnostics)
        self._clock_watch = ClockWatch(self)

    def set_parameters_atomically(self, parameter_list: list[Parameter]) -> SetParametersResult:
        """Set parameters (the parameter service's entry): refuse with a reason or convert.

        An integer for a floating-point parameter is taken as a float; an unknown
        name, a wrong type or value, and ``publish_tf`` without tf2_ros are refused
        with a message naming the parameter (see :meth:`LiveParameters.refusal`).
        """
        params = getattr(self, 'params', None)
        if params is not None:
            parameter_list = params.converted(parameter_list)
            reason = params.refusal(parameter_list)
            if reason is not None:
                return SetParametersResult(successful=False, reason=reason)
        return super().set_parameters_atomically(parameter_list)

    def set_parameters(self, parameter_list: list[Parameter]) -> list[SetParametersResult]:
        """Set parameters one at a time, each as :meth:`set_parameters_atomically` does."""
        return [self.set_parameters_atomically([p]) for p in parameter_list]

    def _warm_up(self, matcher: str) -> None:
        """Compile (or load) the matcher's kernels before the first scan can arrive."""
        note = warm_up([matcher]).note(WARM_UP_NOTE_SECONDS)
        if note:
            self.get_logger().info(note)

    def _log_startup(self) -> None:
        """Say once what the node runs with and where it reads and writes."""
        s = self.params.settings
        m = s.pipeline.mounting
        mounting = ('from TF' if self._tf.use_extrinsic else
                    f'x={m.laser_x} y={m.laser_y} yaw={m.laser_yaw} '
                    f'upside_down={m.laser_upside_down}')
        prior = s.pipeline.motion.prior
        prior_topic = self._priors.topic_name(prior)
        self.get_logger().info(
            f'laser odometry: matcher {s.pipeline.matcher}, reference '
            f'{s.pipeline.local_map.reference}, prior {prior}'
            + (f' from {prior_topic}' if prior_topic else '')
            + f'; {self._scan_sub.topic_name} -> {self._odom_pub.topic_name}, '
            f'{self._pose_pub.topic_name}; frames {s.node.odom_frame} -> '
            f'{s.node.base_frame}; laser mounting {mounting}; TF broadcast '
            f'{"on" if s.node.publish_tf and self._tf.available else "off"}')
        if not self._tf.available:
            self.get_logger().info(
                'tf2_ros is not available: no TF broadcast, laser mounting from the '
                'laser_* parameters' + (' (use_tf_extrinsic ignored)'
                                        if s.node.use_tf_extrinsic else ''))

    def _on_settings(self, changed: dict) -> None:
        """Apply validated parameter changes (called by :class:`LiveParameters`)."""
        settings = self.params.settings
        with self._lock:
            self.pipeline.configure(self.params.pipeline_config())
        self._priors.configure(settings.pipeline.motion.prior, settings.priors)
        self.get_logger().info('parameters set: ' + ', '.join(
            f'{k}={v!r}' for k, v in sorted(changed.items())))

    def _on_scan(self, msg: LaserScanMsg, info: dict[str, Any]) -> None:
        """Match the scan and publish its odometry, or wait for its prior to catch up.

        ``info`` is the message's DDS metadata: a scan received while the previous one
        was being matched waited in the subscription, so the scans missing before it
        were overwritten there because the node was busy.
        """
        received = time.monotonic()
        self._clock_watch.scan_arrived()
        max_gap_ns = int(self.pipeline.config.motion.max_scan_gap * 1e9)
        waited = 0 < (info.get('received_timestamp') or 0) < self._busy_until_ns
        skipped = self._gaps.skipped(stamp_to_ns(msg.header.stamp), max_gap_ns,
                                     info.get('publication_sequence_number'), waited)
        self._received += 1 + skipped.get(BUSY, 0)
        if self._waiting is not None:  # a newer scan: the waiting one goes with what is there
            self._match(self._waiting)
        self._waiting = WaitingScan(msg, skipped, received, -1)
        self._on_prior_wait()

    def _on_prior_wait(self) -> None:
        """Match the waiting scan once its prior has caught up or stopped coming.

        The executor takes one message per subscription and turn, so after a burst the
        wheel odometry or IMU messages up to the scan's stamp may still be queued behind
        it. While the active prior is behind the scan and its messages keep arriving,
        the scan waits a turn of the executor (the guard condition); then it is matched
        with the prior interpolated, not extrapolated, as the replay does.
        """
        waiting = self._waiting
        if waiting is None:
            return
        prior = self.pipeline.config.motion.prior
        arrivals = self._priors.arrivals
        if (self._priors.behind(prior, stamp_to_ns(waiting.msg.header.stamp))
                and arrivals != waiting.arrivals):
            self._waiting = waiting._replace(arrivals=arrivals)
            self._next_turn.trigger()
            return
        self._waiting = None
        self._match(waiting)

    def _match(self, scan: WaitingScan) -> None:
        """Process one scan, then do the next keyframe's own work (errors are logged)."""
        try:
            if self._process(scan.msg, scan.skipped):
                self._latencies.append(time.monotonic() - scan.received)
            with self._lock:  # the next keyframe's own work, once the result is out
                self.pipeline.prepare_next()
        except Exception as error:  # keep running: one bad scan must not stop odometry
            if interrupted(error):
                raise KeyboardInterrupt() from error
            if self.context.ok():
                self.get_logger().error(f'failed to process a scan: {error!r}')
        finally:
            self._busy_until_ns = time.time_ns()

    def _process(self, msg: LaserScanMsg, skipped: dict[str, int]) -> bool:
        """Run one scan through the pipeline and publish the result; True if published.

        ``skipped`` counts the scans that never reached the pipeline since the last
        call, by reason (see :class:`.ScanGapCounter`).
        """
        scan = scan_from_msg(msg)
        with self._lock:
            counters = self.pipeline.counters
            counters.update({k: v for k, v in skipped.items() if v})
            if self._tf.use_extrinsic and not self._update_extrinsic(scan.frame_id):
                counters['extrinsic_missing'] += 1
                return False
            prior = self.pipeline.config.motion.prior
            last = self.pipeline.last_stamp_ns
            step, yaw = self._priors.prior(prior, last, scan.stamp_ns)
            if (prior in ('odom', 'imu') and step is None and yaw is None
                    and last is not None and self.pipeline.keyframe is not None):
                self._priors.warn_missing(prior, scan.stamp_ns)
            estimate = self.pipeline.process(scan, step, yaw)
            node = self.params.settings.node
        if estimate is None:
            return False
        return self._publish(estimate, msg.header.stamp, node.odom_frame, node.base_frame,
                             node.publish_tf, node.publish_debug)

    def _update_extrinsic(self, frame_id: str) -> bool:
        """Apply the TF mounting of ``frame_id``; False while it is unknown."""
        mounting = self._tf.mounting(frame_id)
        if mounting is None:
            return False
        if self.params.tf_mounting != mounting:
            self.params.tf_mounting = mounting
            self.pipeline.configure(self.params.pipeline_config())
        return True

    def _publish(self, estimate: OdometryEstimate, stamp: Time, odom_frame: str,
                 base_frame: str, publish_tf: bool, publish_debug: bool) -> bool:
        """Publish odometry, pose and (optionally) TF with the scan's stamp; True if sent."""
        messages = published_messages(estimate, stamp, odom_frame, base_frame)
        if messages is None:
            self.get_logger().error('non-finite pose estimate not published',
                                    throttle_duration_sec=5.0)
            return False
        self._odom_pub.publish(messages.odometry)
        self._pose_pub.publish(messages.pose)
        if publish_tf:
            self._tf.broadcast(messages.transform)
        if publish_debug:
            cloud = matched_cloud_msg(estimate, stamp, odom_frame)
            if cloud is not None:
                self._cloud_pub.publish(cloud)
            with self._lock:
                self._map_cloud.publish(self.pipeline, stamp, odom_frame)
        return True

    def _on_reset(self, request: Trigger.Request,
                  response: Trigger.Response) -> Trigger.Response:
        """Restart integration at the origin with the next scan as reference."""
        with self._lock:
            self.pipeline.reset()
        response.success = True
        response.message = 'odometry reset to the origin; the next scan is the new reference'
        self.get_logger().info(response.message)
        return response

    def _on_set_pose(self, msg: PoseWithCovarianceStamped) -> None:
        """Restart integration from a given pose (in ``odom_frame``)."""
        odom_frame = self.params.settings.node.odom_frame
        if msg.header.frame_id not in ('', odom_frame):
            self.get_logger().warning(
                f'~/set_pose ignored: pose is in {msg.header.frame_id!r}, not {odom_frame!r}')
            return
        try:
            pose, covariance = initial_pose_from_msg(msg)
        except ValueError as error:
            self.get_logger().warning(f'~/set_pose ignored: {error}')
            return
        with self._lock:
            self.pipeline.reset(pose, covariance)
        self.get_logger().info(
            f'odometry restarted from x={pose[0]:.3f} y={pose[1]:.3f} yaw={pose[2]:.3f}')

    def _publish_diagnostics(self) -> None:
        """Publish the node's health (timer callback, once a second)."""
        with self._lock:
            snapshot = Snapshot(
                time.monotonic(), self._received, self.pipeline.counters.copy(),
                np.array(self.pipeline.processing_times), self.pipeline.matcher.name,
                self.pipeline.config.motion.prior, self._scan_sub.topic_name,
                np.array(self._latencies), self.pipeline.config.local_map.reference)
        status = self._reporter.status(snapshot, self.params.settings.node)
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics_pub.publish(msg)


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C; return the exit code (2 for bad parameters)."""
    return run_node(args, LaserOdomNode, 'laser_odom_node', usage)


if __name__ == '__main__':
    sys.exit(main())
