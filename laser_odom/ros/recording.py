"""The node's messages, serialised exactly as the node sends them, for output bags.

The replay's ``--output-bag`` must hold what a live node would have published for the
same scans, so that a bag replayed into robot_localization (or anything else) sees
live behaviour. Offline, each estimate goes through the node's own builder
(:func:`laser_odom.ros.conversions.published_messages`); with ``--live``, the
odometry the node actually sent is kept as received. Both are serialised by rclpy
(the middleware's CDR), the bytes DDS carries.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from nav_msgs.msg import Odometry
from rclpy.serialization import serialize_message

from laser_odom.core.configuration.node import NodeConfig
from laser_odom.core.pipeline.estimate import OdometryEstimate
from laser_odom.ros.conversions import ns_to_stamp, pose_stamped_from_odometry, published_messages

ODOMETRY_TYPE = 'nav_msgs/msg/Odometry'
POSE_TYPE = 'geometry_msgs/msg/PoseStamped'


@dataclass
class MessageRecorder:
    """Serialised ``odom`` and ``pose`` messages, one pair per published scan."""

    node: NodeConfig
    odometry: list[tuple[int, bytes]] = field(default_factory=list)
    poses: list[tuple[int, bytes]] = field(default_factory=list)

    def add_estimate(self, estimate: OdometryEstimate) -> None:
        """Record what the node publishes for an estimate (nothing if it would not)."""
        messages = published_messages(estimate, ns_to_stamp(estimate.stamp_ns),
                                      self.node.odom_frame, self.node.base_frame)
        if messages is None:
            return
        self.odometry.append((estimate.stamp_ns, serialize_message(messages.odometry)))
        self.poses.append((estimate.stamp_ns, serialize_message(messages.pose)))

    def add_received(self, stamp_ns: int, msg: Odometry) -> None:
        """Record an odometry message received from the node, and its pose."""
        self.odometry.append((stamp_ns, serialize_message(msg)))
        self.poses.append((stamp_ns, serialize_message(pose_stamped_from_odometry(msg))))

    def topics(self) -> dict[str, tuple[str, list[tuple[int, bytes]]]]:
        """Return ``{topic: (message type, [(stamp_ns, bytes)])}`` for the bag writer."""
        return {'/odom': (ODOMETRY_TYPE, sorted(self.odometry, key=lambda m: m[0])),
                '/pose': (POSE_TYPE, sorted(self.poses, key=lambda m: m[0]))}
