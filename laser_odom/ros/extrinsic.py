"""Optional TF: broadcasting ``odom_frame -> base_frame`` and looking up the laser mounting.

tf2_ros is used when it can be imported (any full ROS 2 install); pip-only
environments lack it, and then the node says so once at start-up and carries on with
the ``laser_*`` mounting parameters and without broadcasting.
"""

from __future__ import annotations

import math

from geometry_msgs.msg import TransformStamped
from rclpy.node import Node
from rclpy.time import Time

from laser_odom.core.scan.laser_scan import LaserMounting
from laser_odom.ros.conversions import mounting_from_transform

try:
    import tf2_ros
except ImportError:  # pip-installed rclpy ships without tf2_ros
    tf2_ros = None

TF2_AVAILABLE = tf2_ros is not None
"""Whether tf2_ros could be imported."""

MAX_PLANAR_TILT = math.radians(5.0)
"""A laser tilted more than this from the base plane gets a warning (planar model)."""

WARNING_PERIOD = 5.0
"""Minimum seconds between two warnings about a failed extrinsic lookup."""


class TfInterface:
    """TF broadcaster and extrinsic lookup, both inactive without tf2_ros."""

    def __init__(self, node: Node, base_frame: str, use_extrinsic: bool) -> None:
        """Create the broadcaster (and the listener if the extrinsic comes from TF)."""
        self._node = node
        self._base_frame = base_frame
        self._mountings: dict[str, LaserMounting] = {}
        self.available = TF2_AVAILABLE
        self.use_extrinsic = use_extrinsic and TF2_AVAILABLE
        self._broadcaster = tf2_ros.TransformBroadcaster(node) if TF2_AVAILABLE else None
        self._buffer = None
        if self.use_extrinsic:
            self._buffer = tf2_ros.Buffer()
            self._listener = tf2_ros.TransformListener(self._buffer, node, spin_thread=False)

    def broadcast(self, transform: TransformStamped) -> None:
        """Send ``odom_frame -> base_frame`` (no-op without tf2_ros)."""
        if self._broadcaster is not None:
            self._broadcaster.sendTransform(transform)

    def mounting(self, frame_id: str) -> LaserMounting | None:
        """Return the mounting of laser frame ``frame_id`` on the base, or None if unknown.

        Looked up once per frame and cached; a failed lookup is retried at the next
        scan (the static transform may not have been received yet).
        """
        cached = self._mountings.get(frame_id)
        if cached is not None or self._buffer is None:
            return cached
        try:
            transform = self._buffer.lookup_transform(self._base_frame, frame_id, Time())
        except tf2_ros.TransformException as error:
            self._node.get_logger().warning(
                f'no transform {self._base_frame} <- {frame_id!r} yet ({error}); '
                'skipping scans until it is available', throttle_duration_sec=WARNING_PERIOD)
            return None
        t, r = transform.transform.translation, transform.transform.rotation
        mounting, tilt = mounting_from_transform((t.x, t.y, t.z), (r.x, r.y, r.z, r.w))
        if tilt > MAX_PLANAR_TILT:
            self._node.get_logger().warning(
                f'laser frame {frame_id!r} is tilted {math.degrees(tilt):.1f} deg from the '
                'base plane; the planar model ignores the tilt')
        self._node.get_logger().info(
            f'laser mounting from TF {self._base_frame} <- {frame_id}: x={mounting.x:.3f} '
            f'y={mounting.y:.3f} yaw={mounting.yaw:.3f} upside_down={mounting.upside_down}')
        self._mountings[frame_id] = mounting
        return mounting

    def forget(self) -> None:
        """Drop cached mountings so that they are looked up again."""
        self._mountings.clear()
