"""How accepted matches usually fit: what a new match's residual and overlap are judged against.

A residual or an inlier ratio means little on its own: it depends on the scene (a
cluttered lab, a bare corridor), the scanner's noise and the matcher's metric. The
registrar keeps the medians of the last accepted matches, and a match from a
trusted prediction that fits much worse than them is not trusted
(:meth:`.registrar.Registrar.local_failure`).
"""

from __future__ import annotations

from collections import deque
import math
import statistics

from laser_odom.core.matchers import MatchResult

RESIDUAL_WINDOW = 50
"""Accepted matches whose fit makes the usual level (the medians)."""

MIN_RESIDUAL_SAMPLES = 10
"""The checks against the usual level start once this many matches were accepted."""


class UsualLevel:
    """How accepted matches usually fit: medians of recent residuals and inlier ratios."""

    def __init__(self) -> None:
        """Start with no history."""
        self._residuals: deque[float] = deque(maxlen=RESIDUAL_WINDOW)
        self._inliers: deque[float] = deque(maxlen=RESIDUAL_WINDOW)

    def clear(self) -> None:
        """Forget the history (a new matcher measures its fit differently)."""
        self._residuals.clear()
        self._inliers.clear()

    def add(self, match: MatchResult) -> None:
        """Record how an accepted match fits."""
        if math.isfinite(match.residual) and math.isfinite(match.inlier_ratio):
            self._residuals.append(float(match.residual))
            self._inliers.append(float(match.inlier_ratio))

    def residual(self) -> float | None:
        """Return the median recent residual, None before enough matches."""
        if len(self._residuals) < MIN_RESIDUAL_SAMPLES:
            return None
        return statistics.median(self._residuals)

    def inlier_ratio(self) -> float | None:
        """Return the median recent inlier ratio, None before enough matches."""
        if len(self._inliers) < MIN_RESIDUAL_SAMPLES:
            return None
        return statistics.median(self._inliers)
