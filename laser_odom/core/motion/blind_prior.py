"""The prediction where the scan is blind.

Along a direction the scan hardly constrains (a corridor's axis), a match's estimate is
no better than its covariance says, and zero motion - what a matcher started from
nothing drifts to - is a poor answer when the robot has been driving at a steady
speed. A prediction is better there: the constant-velocity or wheel-odometry guess
when the prediction is trusted and, with ``prior: none``, the translation of the last
well-constrained step when the scans come at a steady rate (the same step again; its
turn is not predicted).

How good such a prediction is, is measured, not assumed: the constant-velocity
prediction of step k is step k - 1 (scaled to the interval), so the spread of the
changes between consecutive well-constrained steps is its error
(:class:`StepHistory`). Along the directions the match does not constrain (its
information below the degeneracy threshold, :mod:`laser_odom.core.registration.acceptance`) the
prediction stands in, with that error as the variance. Where the match has evidence,
even ambiguous evidence (two poses a door apart that fit alike), the prediction only
picks among the poses that fit alike (:mod:`laser_odom.core.registration.registrar`): fused
with a weakly constrained match, a prediction that missed the start of a turn pulled
correct matches away (fr079 every 10th scan: 16 failed steps instead of 6).
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

UNPREDICTED_HEADING = 1e6
"""Heading variance [rad^2] of the last step's motion as a prediction: none. Between
scans seconds apart the robot starts and stops turning at will (and a turn is what
makes a scan pair weak), so only the translation is predicted."""

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
    carried: bool = False
    """Whether the covariance holds the error of a step that was not well constrained,
    which the guess repeats (:meth:`.MotionModel.carried_covariance`)."""


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
        covariance = covariance * (1 + self._since)
        covariance[2, 2] = UNPREDICTED_HEADING
        return Prediction(self._velocities[-1][0] * interval, covariance, 'last_step')
