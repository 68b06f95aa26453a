"""The local map on ``~/local_map``, so that RViz shows what scans are matched against.

With ``reference: local_map`` each scan is matched against a map of recent scans
(:mod:`laser_odom.core.registration.local_map`), not against the previous scan. When
``publish_debug`` is on, the node publishes that map's cells - the mean point of each
cell, in ``odom_frame`` - as a ``sensor_msgs/PointCloud2`` at most once per second of
scan time: the map changes little from one scan to the next, and a full map every
scan would cost more than the scan itself. Where the walls of the map are doubled or
smeared, the odometry drifted while the map was built.

The ``intensity`` field is the cell's weight (observations, less the times a later scan
saw through it): RViz's Intensity colouring shows which walls are firm.
"""

from __future__ import annotations

from builtin_interfaces.msg import Time
import numpy as np
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2, PointField

from laser_odom.core.pipeline.odometry import OdometryPipeline
from laser_odom.ros.conversions import NANOSECONDS, point_cloud_msg, stamp_to_ns

MAP_TOPIC = '~/local_map'
"""The map's topic, under the node's name."""

MAP_PERIOD_NS = NANOSECONDS
"""At most one map per this many nanoseconds of scan stamps (1 Hz)."""

MAP_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
"""The newest map only; kept for a viewer that subscribes later (RViz started after)."""

MAP_FIELDS = [PointField(name=name, offset=4 * k, datatype=PointField.FLOAT32, count=1)
              for k, name in enumerate(('x', 'y', 'z', 'intensity'))]
"""``x y z intensity`` float32 fields: the cell's mean point and its weight."""


def map_cloud_msg(means: np.ndarray, weights: np.ndarray, stamp: Time,
                  frame_id: str) -> PointCloud2:
    """Return cell means (N, 2) and weights (N,) as a ``PointCloud2`` (z = 0)."""
    points = np.zeros((len(means), 4), dtype=np.float32)
    points[:, :2] = means
    points[:, 3] = weights
    return point_cloud_msg(points, MAP_FIELDS, stamp, frame_id)


class MapCloud:
    """Publishes the pipeline's local map on ``~/local_map``, at most once a second."""

    def __init__(self, node: Node) -> None:
        """Create the publisher on ``node``."""
        self._publisher = node.create_publisher(PointCloud2, MAP_TOPIC, MAP_QOS)
        self._last_ns: int | None = None

    @property
    def topic_name(self) -> str:
        """Return the resolved topic name."""
        return self._publisher.topic_name

    def publish(self, pipeline: OdometryPipeline, stamp: Time, frame_id: str) -> bool:
        """Publish the map as it is after the scan stamped ``stamp``; True if sent.

        Nothing is sent when the pipeline matches scan to scan, when the map is
        empty, or when the last map went out less than a second of scan time
        before (a stamp earlier than that one - a looping bag - sends at once).
        """
        stamp_ns = stamp_to_ns(stamp)
        last = self._last_ns
        if last is not None and 0 <= stamp_ns - last < MAP_PERIOD_NS:
            return False
        cells = pipeline.map_cells()
        if cells is None or not len(cells[0]):
            return False
        self._publisher.publish(map_cloud_msg(cells[0], cells[1], stamp, frame_id))
        self._last_ns = stamp_ns
        return True
