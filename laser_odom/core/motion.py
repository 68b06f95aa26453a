"""Motion prediction: the initial guess of each match.

The constant-velocity model assumes the robot keeps the twist of its last step; an
external prior (wheel odometry motion, IMU yaw change) replaces it when configured
and available. The guess only seeds the matcher; a good one keeps ICP-type methods
inside their basin of convergence.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from laser_odom.core import se2
from laser_odom.core.config import MotionConfig


MIN_VELOCITY_DT = 0.005
"""Shortest scan interval [s] from which a velocity is estimated."""


class MotionModel:
    """Predicts the motion between scans from the last velocity or an external prior."""

    def __init__(self, config: MotionConfig) -> None:
        """Create the model; it starts at rest."""
        self.config = config
        self.reset()

    def reset(self) -> None:
        """Forget the velocity (the robot is assumed at rest)."""
        self.velocity = np.zeros(3)

    def predict(self, dt: float, prior_step: se2.Pose | None = None,
                prior_yaw: float | None = None,
                counters: Counter[str] | None = None) -> se2.Pose:
        """Return the predicted motion (base frame of the previous scan) over ``dt``."""
        cfg = self.config
        if cfg.prior == 'none':
            return se2.pose()
        if dt > cfg.max_scan_gap:
            if counters is not None:
                counters['scan_gap'] += 1
            return se2.pose()
        constant_velocity = self.velocity * dt
        if cfg.prior == 'odom':
            if prior_step is not None and se2.is_finite_pose(prior_step):
                return np.array(prior_step, dtype=float)
            if counters is not None:
                counters['prior_missing'] += 1
        elif cfg.prior == 'imu':
            if prior_yaw is not None and np.isfinite(prior_yaw):
                return np.array([constant_velocity[0], constant_velocity[1], prior_yaw])
            if counters is not None:
                counters['prior_missing'] += 1
        return constant_velocity

    def update(self, step: se2.Pose, dt: float) -> None:
        """Record the estimated motion of the last step.

        A step over a gap longer than ``max_scan_gap`` (or a non-finite one) leaves the
        robot assumed at rest. A step over less than ``MIN_VELOCITY_DT`` (scans whose
        stamps nearly coincide, as in re-stamped logs) says nothing reliable about
        speed - millimetres of noise over a microsecond would be km/s - so the previous
        velocity is kept.
        """
        if not (0.0 < dt <= self.config.max_scan_gap and se2.is_finite_pose(step)):
            self.velocity = np.zeros(3)
        elif dt >= MIN_VELOCITY_DT:
            self.velocity = np.array(step, dtype=float) / dt
