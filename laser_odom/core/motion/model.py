"""Motion prediction: the initial guess of each match.

The constant-velocity model assumes the robot keeps the twist of its last step; an
external prior (wheel odometry motion, IMU yaw change) replaces it when configured
and available. The guess only seeds the matcher; a good one keeps ICP-type methods
inside their basin of convergence.
"""

from __future__ import annotations

from collections import Counter, deque
import statistics

import numpy as np

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import MotionConfig


MIN_VELOCITY_DT = 0.005
"""Shortest scan interval [s] from which a velocity is estimated."""


PERIOD_WINDOW = 25
"""Recent scan intervals from which the nominal sensor period is taken."""

JITTER_FRACTION = 0.1
"""Share of off-period intervals (:func:`off_period`) above which scan stamps count as
jittery."""

OFF_PERIOD_TOLERANCE = 0.25
"""How far [periods] an interval may lie from a whole number of periods and still be a
sensor's own: one period, or a few when scans were dropped."""


def off_period(dt: float, period: float) -> bool:
    """Tell whether an interval cannot be a sensor's: not near a whole number of periods.

    A sensor's stamps lie a period apart, or a few when scans are dropped; an interval
    shorter than half the period, or more than :data:`OFF_PERIOD_TOLERANCE` from a whole
    number of periods, was stamped by something else (a logger, a busy driver).
    """
    ratio = dt / period
    return ratio < 0.5 or abs(ratio - round(ratio)) > OFF_PERIOD_TOLERANCE


def fused_with_prediction(guess: se2.Pose, prior_covariance: np.ndarray,
                          measured: se2.Pose, measured_covariance: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Return the prediction corrected by a measured step, and the result's covariance.

    The Kalman update of the constant-velocity state with the step as its measurement
    (Thrun, Burgard and Fox, *Probabilistic Robotics*, table 3.1): ``K = P (P + S)^-1``,
    ``x = g + K (z - g)``, covariance ``(I - K) P``, with ``g`` the predicted step
    and ``P`` its error, ``z`` the measured step and ``S`` its error. Where the scan
    measured well (``S`` far below ``P``) the step stands; where it measured little
    the prediction stays. All three coordinates in one frame (the previous scan's).
    """
    prior = np.asarray(prior_covariance, dtype=float)
    gain = prior @ np.linalg.pinv(prior + np.asarray(measured_covariance, dtype=float))
    innovation = np.asarray(measured, dtype=float) - guess
    innovation[2] = se2.wrap_angle(innovation[2])
    fused = np.asarray(guess, dtype=float) + gain @ innovation
    fused[2] = se2.wrap_angle(fused[2])
    covariance = (np.eye(3) - gain) @ prior
    return fused, 0.5 * (covariance + covariance.T)


class MotionModel:
    """Predicts the motion between scans from the last velocity or an external prior."""

    def __init__(self, config: MotionConfig) -> None:
        """Create the model; it starts at rest."""
        self.config = config
        self.reset()
        self.forget_intervals()

    def reset(self) -> None:
        """Forget the velocity (the robot is assumed at rest)."""
        self.velocity = np.zeros(3)
        self.unmeasured = np.zeros((3, 3))
        """Covariance [(m/s)^2, (rad/s)^2] of the velocity's error that the history of
        well-constrained steps does not measure (:meth:`update`)."""
        self.guess_source = 'none'

    def forget_intervals(self) -> None:
        """Forget the sensor period too (a new sensor or a restarted clock)."""
        self.intervals: deque[float] = deque(maxlen=PERIOD_WINDOW)
        self._period: tuple[float, float, bool] | None = None

    def _period_statistics(self) -> tuple[float, float, bool]:
        """Return the median and mean of the recent intervals and whether they are bursty.

        Computed once per new interval: a scan asks for its effective interval several
        times (prediction, de-skewing, the rate check, the velocity update).
        """
        if self._period is None:  # in Python: numpy's overhead on a few dozen floats is larger
            median = statistics.median(self.intervals)
            off = sum(1 for dt in self.intervals if off_period(dt, median))
            bursty = off / len(self.intervals) > JITTER_FRACTION
            self._period = (median, statistics.fmean(self.intervals), bursty)
        return self._period

    def effective_dt(self, dt: float) -> float:
        """Return the interval the motion is scaled by.

        A sensor's true stamps give intervals of one period, or a few when scans are
        dropped - never much less than one. Logger-stamped logs (the Intel lab log) are
        bursty instead: a scan stamped 10 ms after its predecessor by a 5 Hz sensor was
        taken a whole period later, and the next one looks 0.39 s late. When more than
        ``JITTER_FRACTION`` of the recent intervals are off a whole number of periods
        (:func:`off_period`), the single interval says nothing and the mean interval
        (the true scan rate) is used. fr079 is such a log: a quarter of its intervals
        are 0.55 or 1.45 periods, yet its reference moves as far over them as over a
        whole period (median ratio 1.01 and 1.05; 2.1 over intervals of two periods).
        A lone off-period interval in a regular stream is taken as the whole number of
        median periods nearest to it, at least one (a late stamp after a dropped scan).
        """
        if len(self.intervals) < 5:
            return dt
        median, mean, bursty = self._period_statistics()
        if bursty:
            return mean
        return median * max(1, round(dt / median)) if off_period(dt, median) else dt

    def gap_exceeded(self, dt: float, prior_step: se2.Pose | None = None) -> bool:
        """Tell whether ``dt`` is longer than ``max_scan_gap``: no prediction over it.

        Wheel odometry (``prior: odom``) measures the motion over any gap, so a gap only
        drops an extrapolation: the constant velocity (and the IMU prior's translation).
        """
        return dt > self.config.max_scan_gap and not self._measured(prior_step)

    def _measured(self, prior_step: se2.Pose | None) -> bool:
        """Tell whether the prediction is a measured wheel-odometry step."""
        return (self.config.prior == 'odom' and prior_step is not None
                and se2.is_finite_pose(prior_step))

    def predict(self, dt: float, prior_step: se2.Pose | None = None,
                prior_yaw: float | None = None,
                counters: Counter[str] | None = None) -> se2.Pose:
        """Return the predicted motion (base frame of the previous scan) over ``dt``.

        :attr:`guess_source` then names where it came from: ``none`` (no prior, or a
        gap), ``odom``, ``imu`` (its yaw, the constant velocity's translation) or
        ``constant_velocity`` - also when the configured odom or IMU prior is missing
        and the constant velocity stands in.
        """
        cfg = self.config
        self.guess_source = 'none'
        if cfg.prior == 'none' or self.gap_exceeded(dt, prior_step):
            return se2.pose()
        constant_velocity = self.velocity * self.effective_dt(dt)
        if cfg.prior == 'odom':
            if prior_step is not None and se2.is_finite_pose(prior_step):
                self.guess_source = 'odom'
                return np.array(prior_step, dtype=float)
            if counters is not None:
                counters['prior_missing'] += 1
        elif cfg.prior == 'imu':
            if prior_yaw is not None and np.isfinite(prior_yaw):
                self.guess_source = 'imu'
                return np.array([constant_velocity[0], constant_velocity[1], prior_yaw])
            if counters is not None:
                counters['prior_missing'] += 1
        self.guess_source = 'constant_velocity'
        return constant_velocity

    def update(self, step: se2.Pose, dt: float,
               unmeasured: np.ndarray | None = None) -> None:
        """Record the estimated motion of the last step.

        A step over a gap longer than ``max_scan_gap`` (or a non-finite one) leaves the
        robot assumed at rest. The step is turned into a velocity over the
        :meth:`effective_dt`, so near-coincident stamps (millimetres of motion over a
        microsecond would be km/s) do not make the next prediction run away.

        ``unmeasured`` is the step's error when it was not well constrained
        (degenerate, weak): its covariance, or that of the prediction corrected by it
        (:func:`fused_with_prediction`). The prediction's measured error
        (:class:`.blind_prior.StepHistory`) comes from consecutive well-constrained
        steps and does not hold it, so the velocity carries it on as its own
        (:meth:`carried_covariance`).
        """
        if dt > 0.0:
            self.intervals.append(dt)
            self._period = None
        if not (0.0 < dt <= self.config.max_scan_gap and se2.is_finite_pose(step)):
            self.velocity = np.zeros(3)
            self.unmeasured = np.zeros((3, 3))
            return
        effective = self.effective_dt(dt)
        if effective >= MIN_VELOCITY_DT:
            self.velocity = np.array(step, dtype=float) / effective
            self.unmeasured = (np.zeros((3, 3)) if unmeasured is None else
                               np.array(unmeasured, dtype=float) / (effective * effective))

    def carried_covariance(self, dt: float) -> np.ndarray:
        """Return the covariance the last guess carries from a step not well constrained.

        The constant-velocity guess over ``dt`` is the last step scaled to the interval
        (``v dt``), so a step that erred by ``e`` sends the guess ``e`` off: its
        covariance ``S`` scaled by ``(dt / dt_step)^2``. Nothing for a guess from wheel
        odometry; only the translation for the IMU's (its yaw is measured).
        """
        if self.guess_source not in ('constant_velocity', 'imu'):
            return np.zeros((3, 3))
        effective = self.effective_dt(dt)
        carried = self.unmeasured * (effective * effective)
        if self.guess_source == 'imu':
            carried[2, :] = carried[:, 2] = 0.0
        return carried
