"""The prediction where the scan is blind.

Along a direction the scan hardly constrains (a corridor's axis), a match's estimate is
no better than its covariance says, and zero motion - what a matcher started from
nothing drifts to - is a poor answer when the robot has been driving at a steady
speed. A prediction is better there: the constant-velocity or wheel-odometry guess
when the prediction is trusted and, with ``prior: none``, the motion of the last
well-constrained step when the scans come at a steady rate (the same step again).

How good such a prediction is, is measured, not assumed: the constant-velocity
prediction of step k is step k - 1 (scaled to the interval), so the spread of the
changes between consecutive well-constrained steps is its error
(:class:`StepHistory`). The prediction and the match are then fused as two independent
estimates (the information form of the Kalman update, Bar-Shalom, Li & Kirubarajan
2001, Sec. 2.6): ``P = (P_m^-1 + P_p^-1)^-1``, ``x = P (P_m^-1 x_m + P_p^-1 x_p)``.
Where the match is well constrained it keeps its value and its covariance; where it is
blind it takes the prediction and the prediction's covariance.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from laser_odom.core import se2

HISTORY = 20
"""Recent well-constrained steps kept: the spread of their changes is the prediction's
error."""

MIN_HISTORY = 4
"""No prediction before this many pairs of consecutive well-constrained steps."""

STEADY_RATE = 0.25
"""Scans come at a steady rate when the interval differs from the last one by at most
this fraction: then the last step's motion predicts the next (with ``prior: none``)."""

PREDICTION_FLOOR = np.array([0.01, 0.01, 0.005]) ** 2
"""Smallest variance [m^2, m^2, rad^2] of a prediction: a robot never repeats a step to
the millimetre, however steadily it drove so far."""


@dataclass(frozen=True)
class Prediction:
    """A predicted step, its covariance and where it comes from.

    ``pose`` is the current scan's predicted pose in the reference frame; ``source`` is
    ``prior`` (the trusted guess) or ``last_step`` (the last well-constrained step's
    motion).
    """

    pose: np.ndarray
    covariance: np.ndarray
    source: str


class StepHistory:
    """Accepted steps and the velocities of the well-constrained ones: the evidence."""

    def __init__(self) -> None:
        """Start with no history."""
        self._velocities: deque[tuple[np.ndarray, bool]] = deque(maxlen=HISTORY)
        self._last: tuple[int, int] | None = None
        self._since = 0

    def add(self, start_ns: int, end_ns: int, step: se2.Pose, well_constrained: bool) -> None:
        """Record an accepted step from the scan at ``start_ns`` to the one at ``end_ns``.

        A well-constrained step's velocity joins the history (marked consecutive when
        the step before it was well constrained too, and ended where it starts).
        """
        if end_ns <= start_ns:
            return
        consecutive = self._last is not None and self._last[1] == start_ns and self._since == 0
        if well_constrained:
            velocity = np.array(step, dtype=float) / ((end_ns - start_ns) * 1e-9)
            self._velocities.append((velocity, consecutive))
            self._since = 0
        else:
            self._since += 1
        self._last = (start_ns, end_ns)

    def covariance(self, interval: float) -> np.ndarray | None:
        """Return the error covariance of a constant-velocity step over ``interval`` [s].

        Consecutive well-constrained steps' velocities differ by ``dv``; over
        ``interval`` the prediction errs by ``dv * interval``. None before
        :data:`MIN_HISTORY` such pairs.
        """
        velocities = list(self._velocities)
        changes = [velocity - previous[0] for previous, (velocity, consecutive)
                   in zip(velocities, velocities[1:]) if consecutive]
        if len(changes) < MIN_HISTORY:
            return None
        variance = np.mean(np.square(np.array(changes) * interval), axis=0)
        return np.diag(np.maximum(variance, PREDICTION_FLOOR))

    def last_step(self, start_ns: int, end_ns: int) -> Prediction | None:
        """Return the last well-constrained step's motion as the step to ``end_ns``.

        Only when the reference is the scan the last accepted step ended at and the
        interval is steady (within :data:`STEADY_RATE` of the last one). Each accepted
        step since the last well-constrained one (the velocity may have changed) adds
        one more prediction error to the covariance. None otherwise.
        """
        if self._last is None or not self._velocities or self._last[1] != start_ns:
            return None
        interval = (end_ns - start_ns) * 1e-9
        previous = (self._last[1] - self._last[0]) * 1e-9
        if abs(interval - previous) > STEADY_RATE * previous:
            return None
        covariance = self.covariance(interval)
        if covariance is None:
            return None
        return Prediction(self._velocities[-1][0] * interval, covariance * (1 + self._since),
                          'last_step')


def fuse(pose: se2.Pose, covariance: np.ndarray,
         prediction: Prediction) -> tuple[np.ndarray, np.ndarray]:
    """Return the match fused with the prediction: ``(pose, covariance)``.

    Information form of two independent Gaussian estimates (module docstring); the
    heading difference is wrapped. A singular match covariance (a direction with no
    variance) keeps the match there.
    """
    match_information = np.linalg.pinv(covariance, hermitian=True)
    prediction_information = np.linalg.inv(prediction.covariance)
    fused = np.linalg.inv(match_information + prediction_information)
    offset = np.asarray(prediction.pose, dtype=float) - pose
    offset[2] = se2.wrap_angle(offset[2])
    out = np.asarray(pose, dtype=float) + fused @ prediction_information @ offset
    out[2] = se2.wrap_angle(out[2])
    return out, 0.5 * (fused + fused.T)
