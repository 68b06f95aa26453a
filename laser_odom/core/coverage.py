"""How much of a run a reference covers: judged by time span, not by the share of poses.

A reference is often a set of keyframes: MIT CSAIL's official one pairs with 686 of its
1988 scans (35 %), Intel's with one scan in 16, yet both span the whole run, and an ATE
or RPE over them scores all of it. What makes a comparison meaningless is a reference
of another run or another clock (it pairs with almost nothing), or one that stops
early or has long holes (it scores only part of the run). So the coverage of a run is
the share of its duration that lies between paired poses close enough together: two
consecutive paired stamps cover the time between them when they are at most
:func:`max_hole` apart. The replay (``--min-coverage``), the benchmark's ``--bag`` and
``laser_odom_tune`` all judge a reference by :func:`reference_coverage`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from laser_odom.core.metrics import associate
from laser_odom.core.trajectory import Trajectory

MIN_HOLE_SECONDS = 2.0
"""Paired poses this close [s] always cover the time between them."""

HOLE_SCAN_PERIODS = 20
"""...and so do poses up to this many median scan periods apart (slow scanners)."""


@dataclass(frozen=True)
class Coverage:
    """What a reference covers of a run: paired poses and the share of the run's time."""

    paired: int
    total: int
    span: float
    """Share of the run's duration (first to last stamp) that the paired poses cover."""
    hole: float
    """Paired poses farther apart than this [s] leave the time between them uncovered."""

    @property
    def share(self) -> float:
        """Return the share of the run's poses that pair with a reference pose."""
        return self.paired / self.total if self.total else 0.0

    def describe(self) -> str:
        """Return e.g. ``686 of 1988 poses paired (35 %), covering 99 % of the run in time``."""
        return (f'{self.paired} of {self.total} poses paired ({percent(self.share)}), '
                f'covering {percent(self.span)} of the run in time')


def percent(share: float) -> str:
    """Return a share as a rounded percentage, ``'35 %'``."""
    return f'{100.0 * share:.0f} %'


def max_hole(stamps_ns: np.ndarray) -> float:
    """Return the longest gap [s] between paired poses that still covers the time between.

    ``MIN_HOLE_SECONDS``, or :data:`HOLE_SCAN_PERIODS` median scan periods on a slow
    scanner (a keyframe reference of a 5 Hz log is a few seconds apart).
    """
    if len(stamps_ns) < 2:
        return MIN_HOLE_SECONDS
    period = float(np.median(np.diff(np.sort(stamps_ns)))) * 1e-9
    return max(MIN_HOLE_SECONDS, HOLE_SCAN_PERIODS * period)


def reference_coverage(stamps_ns: np.ndarray, reference: Trajectory) -> Coverage:
    """Return how much of the run stamped ``stamps_ns`` the reference covers.

    Poses pair with reference poses as the metrics pair them (stamps within 10 ms,
    :func:`laser_odom.core.metrics.associate`). A run of one stamp is covered when it
    pairs.
    """
    stamps = np.sort(np.asarray(stamps_ns, dtype=np.int64))
    run = Trajectory(stamps, np.zeros((len(stamps), 3)))
    _, paired_index = associate(run, reference)
    hole = max_hole(stamps)
    total = len(stamps)
    paired = np.sort(stamps[paired_index])
    duration = (stamps[-1] - stamps[0]) * 1e-9 if total else 0.0
    if duration <= 0.0:
        span = 1.0 if len(paired) else 0.0
    else:
        gaps = np.diff(paired) * 1e-9
        span = float(np.sum(gaps[gaps <= hole])) / duration
    return Coverage(len(paired), total, span, hole)
