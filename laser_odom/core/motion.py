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
        """Record the estimated motion of the last step."""
        if dt > 0.0 and dt <= self.config.max_scan_gap and se2.is_finite_pose(step):
            self.velocity = np.array(step, dtype=float) / dt
        else:
            self.velocity = np.zeros(3)
