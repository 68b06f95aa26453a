"""How much of a run a reference covers: judged by time span, not by the share of poses.

A reference is often a set of keyframes: MIT CSAIL's official one pairs with 686 of its
1988 scans (35 %), Intel's with one scan in 16, yet both span the whole run, and an ATE
or RPE over them scores all of it. What makes a comparison meaningless is a reference
of another run or another clock (its poses fall within the run but pair with almost
no scan), or one that stops early or has long holes (it scores only part of the run).
So a reference's coverage of a run is the smaller of two shares:

- in time: the share of the run's duration that lies between paired poses close enough
  together - at most :func:`max_hole` apart, which scales with the scan period and with
  the reference's own spacing, so keyframes a few seconds apart cover the time between
  them and a stretch without any pose does not;
- in poses: the share of the reference's poses within the run that pair with a scan
  (of at most as many as there are scans: a 100 Hz ground truth pairs with every scan,
  not with every one of its poses).

The replay (``--min-coverage``), the benchmark's ``--bag`` and ``laser_odom_tune`` all
judge a reference by :func:`reference_coverage`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from laser_odom.core.evaluation.metrics import associate, DEFAULT_MAX_OFFSET_NS
from laser_odom.core.trajectory import Trajectory

MIN_HOLE_SECONDS = 2.0
"""Paired poses this close [s] always cover the time between them."""

HOLE_SCAN_PERIODS = 20
"""...and so do poses up to this many median scan periods apart (slow scanners)..."""

HOLE_REFERENCE_SPACINGS = 3
"""...or up to this many times the median spacing of the paired poses (keyframes)."""


@dataclass(frozen=True)
class Coverage:
    """What a reference covers of a run: paired poses, and the shares in time and poses."""

    paired: int
    total: int
    span: float
    """Share of the run's duration (first to last stamp) that the paired poses cover."""
    hole: float
    """Paired poses farther apart than this [s] leave the time between them uncovered."""
    poses: float = 1.0
    """Share of the reference's poses within the run that pair with a scan (of at most
    as many as the run has)."""

    @property
    def share(self) -> float:
        """Return the share of the run's poses that pair with a reference pose."""
        return self.paired / self.total if self.total else 0.0

    @property
    def fraction(self) -> float:
        """Return the coverage judged against ``--min-coverage``: the smaller share."""
        return min(self.span, self.poses)

    def describe(self) -> str:
        """Return e.g. ``686 of 1988 poses paired (35 %), covering 99 % of the run in time``."""
        text = (f'{self.paired} of {self.total} poses paired ({percent(self.share)}), '
                f'covering {percent(self.span)} of the run in time')
        if self.poses < 1.0:
            text += f' ({percent(self.poses)} of its poses within the run paired)'
        return text

    def shortfall(self) -> str:
        """Return why the coverage is low, for an error message."""
        if self.poses < self.span:
            return (f'only {percent(self.poses)} of its poses within the run pair with a '
                    f'scan ({self.paired} of {self.total} scans paired): another clock or '
                    'another run?')
        return (f'it covers only {percent(self.span)} of the run in time ({self.paired} of '
                f'{self.total} poses paired; poses more than {self.hole:.3g} s apart leave '
                'the time between them uncovered)')


def percent(share: float) -> str:
    """Return a share as a rounded percentage, ``'35 %'``."""
    return f'{100.0 * share:.0f} %'


def max_hole(stamps_ns: np.ndarray, paired_ns: np.ndarray | None = None) -> float:
    """Return the longest gap [s] between paired poses that still covers the time between.

    :data:`MIN_HOLE_SECONDS`, :data:`HOLE_SCAN_PERIODS` median scan periods, or
    :data:`HOLE_REFERENCE_SPACINGS` times the median spacing of the paired poses,
    whichever is longest.
    """
    hole = MIN_HOLE_SECONDS
    for stamps, factor in ((stamps_ns, HOLE_SCAN_PERIODS),
                           (paired_ns, HOLE_REFERENCE_SPACINGS)):
        if stamps is not None and len(stamps) >= 2:
            hole = max(hole, factor * float(np.median(np.diff(np.sort(stamps)))) * 1e-9)
    return hole


def reference_coverage(stamps_ns: np.ndarray, reference: Trajectory) -> Coverage:
    """Return how much of the run stamped ``stamps_ns`` the reference covers.

    Poses pair with reference poses as the metrics pair them (stamps within 10 ms,
    :func:`laser_odom.core.evaluation.metrics.associate`). A run of one stamp is covered when it
    pairs.
    """
    stamps = np.sort(np.asarray(stamps_ns, dtype=np.int64))
    run = Trajectory(stamps, np.zeros((len(stamps), 3)))
    _, paired_index = associate(run, reference)
    total = len(stamps)
    paired = np.sort(stamps[paired_index])
    hole = max_hole(stamps, paired)
    if total == 0 or len(paired) == 0:
        return Coverage(len(paired), total, 0.0, hole, 0.0)
    duration = (stamps[-1] - stamps[0]) * 1e-9
    if duration <= 0.0:
        span = 1.0
    else:
        gaps = np.diff(paired) * 1e-9
        span = float(np.sum(gaps[gaps <= hole])) / duration
    tolerance = DEFAULT_MAX_OFFSET_NS
    within = np.count_nonzero((reference.stamps_ns >= stamps[0] - tolerance)
                              & (reference.stamps_ns <= stamps[-1] + tolerance))
    poses = len(paired) / max(min(within, total), 1)
    return Coverage(len(paired), total, span, hole, min(poses, 1.0))
