"""``laser_odom_replay --live --clock``: the sim time of a node run with ``use_sim_time``.

A node on sim time takes its ROS time from ``/clock``; with none it stands at zero and
the node's once-a-second ``/diagnostics`` report never comes. :class:`ReplayClock`
publishes each scan's stamp on ``/clock`` before the scan (as ``ros2 bag play --clock``
does), and while the replay waits for a report - before the first scan and after the
last - lets the clock run on at the real rate: from :data:`PRE_ROLL` seconds before
the first stamp (so that it never reaches it) and from the last one.
"""

from __future__ import annotations

import time
from typing import Callable

from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from laser_odom.ros.conversions import ns_to_stamp

CLOCK_TOPIC = '/clock'

PRE_ROLL = 3.0
"""Seconds before the first scan's stamp where the clock starts (more than a report wait)."""

TICK = 0.05
"""Seconds between two ``/clock`` messages while the clock runs on its own."""


class ReplayClock:
    """``/clock`` of a live replay: the scans' stamps, running on between runs of scans."""

    def __init__(self, node: Node) -> None:
        """Create the ``/clock`` publisher (reliable: any subscriber's QoS accepts it)."""
        self._pub = node.create_publisher(
            Clock, CLOCK_TOPIC, QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        self.now_ns: int | None = None

    def publish(self, stamp_ns: int) -> None:
        """Publish ``stamp_ns`` as the current time."""
        self._pub.publish(Clock(clock=ns_to_stamp(stamp_ns)))
        self.now_ns = stamp_ns

    def start_before(self, first_ns: int) -> None:
        """Start the clock :data:`PRE_ROLL` seconds before the first scan's stamp."""
        self.publish(first_ns - int(PRE_ROLL * 1e9))

    def running(self) -> Callable[[], None]:
        """Return ``tick()``, which advances the clock from now at the real rate."""
        origin, start = self.now_ns, time.monotonic()

        def tick() -> None:
            if origin is not None:
                self.publish(origin + int((time.monotonic() - start) * 1e9))
        return tick
