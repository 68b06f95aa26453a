"""The node's external motion priors: wheel odometry and IMU subscriptions feeding buffers.

Only the prior named by the ``prior`` parameter is subscribed to (``wheel_odom``,
``nav_msgs/Odometry``, or ``imu``, ``sensor_msgs/Imu``; relative, remappable names), so
an unused prior costs nothing. The buffering and interpolation are ROS-free
(:mod:`laser_odom.core.motion.priors`) and shared with the replay harness.
"""

from __future__ import annotations

import threading

from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data, QoSProfile
from rclpy.subscription import Subscription
from sensor_msgs.msg import Imu

from laser_odom.core import se2
from laser_odom.core.configuration.node import PriorConfig
from laser_odom.core.motion.priors import external_prior, ImuBuffer, OdometryBuffer
from laser_odom.ros.conversions import imu_yaw_from_msg, odometry_pose_from_msg

PRIOR_QOS = QoSProfile(
    history=qos_profile_sensor_data.history, depth=100,
    reliability=qos_profile_sensor_data.reliability,
    durability=qos_profile_sensor_data.durability)
"""Best effort (matches reliable and best-effort publishers); deep enough for bursts."""

PRIOR_TOPICS = {'odom': 'wheel_odom', 'imu': 'imu'}
"""Topic of each external prior (relative, so namespaces and remapping apply)."""

WARNING_PERIOD = 5.0
"""Minimum seconds between two warnings about a missing or stale prior."""


class PriorInputs:
    """Subscriptions and time buffers of the wheel odometry and IMU priors."""

    def __init__(self, node: Node, config: PriorConfig) -> None:
        """Create empty buffers; :meth:`configure` subscribes."""
        self._node = node
        self._lock = threading.Lock()
        self.odometry = OdometryBuffer(config)
        self.imu = ImuBuffer(config)
        self._subscriptions: dict[str, Subscription] = {}
        self.arrivals = 0
        """Prior messages received so far (both topics)."""

    def configure(self, prior: str, config: PriorConfig) -> None:
        """Subscribe to the topic ``prior`` needs and drop the other subscription."""
        with self._lock:
            self.odometry.config = config
            self.imu.config = config
        for name, topic in PRIOR_TOPICS.items():
            if name == prior and name not in self._subscriptions:
                msg_type, callback = ((Odometry, self._on_odometry) if name == 'odom'
                                      else (Imu, self._on_imu))
                self._subscriptions[name] = self._node.create_subscription(
                    msg_type, topic, callback, PRIOR_QOS)
            elif name != prior and name in self._subscriptions:
                self._node.destroy_subscription(self._subscriptions.pop(name))
                with self._lock:
                    self._buffer(name).clear()

    def topic_name(self, prior: str) -> str | None:
        """Return the resolved topic of the active prior subscription, if any."""
        subscription = self._subscriptions.get(prior)
        return subscription.topic_name if subscription is not None else None

    def _buffer(self, prior: str) -> OdometryBuffer | ImuBuffer:
        """Return the buffer of an external prior (``odom`` or ``imu``)."""
        return self.odometry if prior == 'odom' else self.imu

    def behind(self, prior: str, stamp_ns: int) -> bool:
        """Return whether the active external prior has data, but none at ``stamp_ns`` yet."""
        if prior not in PRIOR_TOPICS:
            return False
        with self._lock:
            newest = self._buffer(prior).newest_ns
        return newest is not None and newest < stamp_ns

    def _on_odometry(self, msg: Odometry) -> None:
        """Buffer one wheel odometry pose."""
        self.arrivals += 1
        stamp_ns, pose = odometry_pose_from_msg(msg)
        if se2.is_finite_pose(pose):
            with self._lock:
                self.odometry.add(stamp_ns, pose)

    def _on_imu(self, msg: Imu) -> None:
        """Buffer one IMU yaw / yaw rate sample."""
        self.arrivals += 1
        stamp_ns, yaw, rate = imu_yaw_from_msg(msg)
        if rate == rate and (yaw is None or yaw == yaw):
            with self._lock:
                self.imu.add(stamp_ns, yaw, rate)

    def prior(self, prior: str, start_ns: int | None,
              end_ns: int) -> tuple[se2.Pose | None, float | None]:
        """Return ``(prior_step, prior_yaw)`` between two scan stamps (None when stale)."""
        with self._lock:
            return external_prior(prior, start_ns, end_ns, self.odometry, self.imu)

    def warn_missing(self, prior: str, end_ns: int) -> None:
        """Log (throttled) that the prior is missing or stale and constant velocity is used."""
        with self._lock:
            newest = self._buffer(prior).newest_ns
        topic = self.topic_name(prior) or PRIOR_TOPICS.get(prior, prior)
        detail = ('no message received yet' if newest is None
                  else f'newest message is {(end_ns - newest) * 1e-9:+.3f} s from the scan')
        self._node.get_logger().warning(
            f'{prior} prior on {topic} missing or stale ({detail}); using constant velocity',
            throttle_duration_sec=WARNING_PERIOD)
