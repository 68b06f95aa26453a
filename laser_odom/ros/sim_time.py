"""Sim time without a clock: the node says once why its ROS time stands still.

With ``use_sim_time: true`` a node's ROS time is what ``/clock`` says, and before the
first ``/clock`` message it stands at zero. Everything paced or stamped by ROS time
stands with it: the node's ``/diagnostics`` report (a timer of one ROS second) never
comes, while the odometry, stamped with the scans' own stamps, still goes out. Without
a word from the node that looks like a dead node (``laser_odom_ctl status`` hears
nothing), so :class:`ClockWatch` warns once, naming ``use_sim_time`` and ``/clock``, as
soon as scans arrive with no clock, or after :data:`NO_CLOCK_PATIENCE` seconds without
either. ``laser_odom_replay --live --clock`` and ``ros2 bag play --clock`` publish one.
"""

from __future__ import annotations

import time

from rclpy.clock import Clock, ClockType
from rclpy.node import Node

NO_CLOCK_PATIENCE = 5.0
"""Seconds (steady time) of sim time with no ``/clock`` after which the node says so."""

CHECK_PERIOD = 1.0
"""Seconds (steady time) between two looks at the clock."""

NO_CLOCK_WARNING = (
    'use_sim_time is true but nothing has arrived on /clock: ROS time stands at 0, so '
    'the once-a-second /diagnostics report never comes (odometry still goes out, '
    'stamped by the scans); publish /clock (ros2 bag play --clock, laser_odom_replay '
    '--live --clock) or run with use_sim_time:=false')
"""What the node says, once, when it runs on sim time that never started."""


class ClockWatch:
    """Warn once when the node runs on sim time and no ``/clock`` has arrived.

    It looks on a steady timer (a ROS timer would stand still with the clock it
    watches) and at the first scan; once it has spoken it stops looking.
    """

    def __init__(self, node: Node) -> None:
        """Start watching ``node``'s clock."""
        self._node = node
        self._scans = False
        self._since: float | None = None
        self.warned = False
        self._timer = node.create_timer(CHECK_PERIOD, self._check,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))

    def scan_arrived(self) -> None:
        """Note that scans arrive: a scan with no clock is reason enough to say it."""
        if not self._scans:
            self._scans = True
            self._check()

    def _check(self) -> None:
        """Warn if sim time is on, no clock came, and scans or the patience ran out."""
        if self.warned:
            return
        clock = self._node.get_clock()
        if not clock.ros_time_is_active:  # use_sim_time false (it may be set later)
            self._since = None
            return
        now = time.monotonic()
        self._since = self._since if self._since is not None else now
        if clock.now().nanoseconds != 0:  # a /clock message has arrived
            self._stop()
            return
        if self._scans or now - self._since >= NO_CLOCK_PATIENCE:
            self._node.get_logger().warning(NO_CLOCK_WARNING)
            self.warned = True
            self._stop()

    def _stop(self) -> None:
        """Stop looking: the clock runs, or the warning was given."""
        self._timer.cancel()
