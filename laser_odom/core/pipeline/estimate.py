"""What the pipeline gives back per scan, and the names of what it counts.

:class:`OdometryEstimate` is the one result the node turns into messages, the replay
into a trajectory and the benchmark into scores; :data:`OUTCOMES` and :data:`EVENTS`
name the counters the diagnostics and the replay's report show.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from laser_odom.core.matchers import MatchResult
from laser_odom.core.pipeline.announce import EVIDENCE_EVENTS
from laser_odom.core.preprocess.deskew import DESKEW_EVENTS
from laser_odom.core.registration.map_registrar import MAP_EVENTS
from laser_odom.core.registration.registrar import SEARCH_TRIGGERS

OUTCOMES = ('scans_in', 'processed', 'initialized', 'matched', 'degenerate', 'rejected')
"""Counters of what became of the scans; every other counter is a skip reason, a
rejection reason (``rejected_<reason>``) or one of the :data:`EVENTS`."""

EVENTS = ('prior_missing', 'scan_gap', 'time_jump_back', 'ambiguous') + tuple(
    f'search_{trigger}' for trigger in SEARCH_TRIGGERS) + EVIDENCE_EVENTS + tuple(
    DESKEW_EVENTS) + MAP_EVENTS
"""Counters of events that do not skip the scan: a missing or dropped prior, a clock
jump, an ambiguous match, each reason the global search ran, sweep timing that was
repaired or ignored, and what the local map did."""


UNKNOWN_TWIST_VARIANCE = 1.0e3
"""Variance [(m/s)^2, (rad/s)^2] of the twist before the first match has measured one.

The first scan after a start or reset has nothing to be matched against, so its
zero twist is a placeholder, not a measurement: a filter fusing it must not take it
for "standing still". 1e3 (a standard deviation of 32 m/s) is the order
robot_localization's migration guide names for a covariance meant to make a filter
ignore a value, and the largest it takes on a fused variable without a diagnostics
warning (it warns above 1e3; docs/robot_localization.md)."""


@dataclass
class OdometryEstimate:
    """Odometry after one scan: pose of the base in the odom frame, and its twist.

    ``twist`` is ``[vx, vy, wz]`` in the base frame (REP-105); covariances are 3x3 in
    ``[x, y, yaw]``. ``status`` is ``initialized``, ``matched``, ``degenerate`` or
    ``rejected``; ``processing_time`` is seconds spent on this scan.
    """

    stamp_ns: int
    pose: np.ndarray
    pose_covariance: np.ndarray
    twist: np.ndarray
    twist_covariance: np.ndarray
    status: str
    match: MatchResult | None = None
    processing_time: float = 0.0
    scan_points: np.ndarray | None = None
    """The scan's points in the base frame (N, 2), as matched."""
    step_covariance: np.ndarray | None = None
    """Covariance (3x3) of the match this pose comes from (the step from the previous
    scan, the keyframe or the previous pose on the local map, with the doubt of a
    disputed map match added), before it is divided by dt^2 into the twist's; None for
    an ``initialized`` scan."""
