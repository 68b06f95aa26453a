"""Shared pieces of the dataset importers: errors, beam geometry, no-return readings, stamps.

Every importer turns a file into a :class:`laser_odom.core.trajectory.Dataset`; the rules
that the formats share (how CARMEN-style beam counts map to angles, which readings mean
"no return", how a log's jittery clock is made strictly increasing, how a derived
``reference_keyframes.txt`` is joined to the scans) live here so that they are applied
identically to every format.

Malformed input policy: a malformed line is reported as ``file:line: what is wrong``. By
default it is skipped and the loader logs a warning (the first few lines in full plus a
count) through the ``laser_odom.core.datasets`` logger, because one broken line in a log
of thousands of scans should not make the whole log unusable; ``strict=True`` raises
:class:`DatasetError` at the first one instead. A file with no usable laser data at all is
always a :class:`DatasetError`.
"""

from __future__ import annotations

import bisect
import logging
import math
from pathlib import Path

import numpy as np

from laser_odom.core import se2
from laser_odom.core.scan.laser_scan import LaserScan
from laser_odom.core.trajectory import Trajectory

LOGGER = logging.getLogger('laser_odom.core.datasets')

#: SICK LMS 2xx scanners measure at most 80 m (fr079's log says ``robot_front_laser_max
#: 80.99``); readings from 81 m up are the scanner's "no echo" / "dazzled" codes, logged as
#: 81.83 m (Intel) or 81.91 m (MIT CSAIL, fr079).
SICK_NO_RETURN_M = 81.0
#: A log's largest reading counts as a driver's max-range fill value (e.g. 50 m) only when
#: it is at least this long and repeats (see :func:`no_return_threshold`).
MIN_FILL_VALUE_M = 20.0
#: Minimum spacing forced between consecutive scan stamps (1 microsecond, the resolution
#: of the logs' clocks), so that :class:`Trajectory` interpolation never divides by zero.
MIN_STAMP_STEP_NS = 1000
#: How many malformed lines are logged one by one before only the count is given.
MAX_LOGGED_ISSUES = 5


class DatasetError(ValueError):
    """A dataset file is missing, unreadable or has no usable laser data."""


class LineIssues:
    """Collect per-line problems of one file: raise at once when strict, else skip and log."""

    def __init__(self, path: Path | str, strict: bool = False) -> None:
        """Start an empty report for ``path``."""
        self.path = str(path)
        self.strict = strict
        self.messages: list[str] = []

    def add(self, lineno: int | str, what: str) -> None:
        """Record that line ``lineno`` is unusable (raise :class:`DatasetError` if strict)."""
        message = f'{self.path}:{lineno}: {what}'
        if self.strict:
            raise DatasetError(message)
        self.messages.append(message)

    def __len__(self) -> int:
        """Return the number of skipped lines."""
        return len(self.messages)

    def log(self) -> None:
        """Log the first few problems in full and how many more lines were skipped."""
        for message in self.messages[:MAX_LOGGED_ISSUES]:
            LOGGER.warning('%s (line skipped)', message)
        extra = len(self.messages) - MAX_LOGGED_ISSUES
        if extra > 0:
            LOGGER.warning('%s: %d more malformed lines skipped', self.path, extra)


def carmen_beam_geometry(count: int, start: float = -math.pi / 2,
                         fov: float = math.pi) -> tuple[float, float, float]:
    """Return ``(angle_min, angle_max, angle_increment)`` of ``count`` beams over ``fov``.

    The CARMEN convention (data README): beams start at ``start`` (-90 deg) and spread
    over the field of view; an odd count includes both ends (181 -> 1 deg steps to +90,
    361 -> 0.5 deg steps to +90) while an even count leaves the last step out (180 -> 1 deg
    steps to +89, 360 -> 0.5 deg steps to +89.5). ``angle_max`` is the last beam's angle,
    as in ``sensor_msgs/LaserScan``.
    """
    if count < 2:
        raise ValueError(f'a scan needs at least 2 beams, got {count}')
    increment = fov / (count - 1) if count % 2 else fov / count
    return start, start + (count - 1) * increment, increment


def no_return_threshold(ranges: np.ndarray) -> float:
    """Return the smallest reading of a log that means "no return" (inf when there is none).

    Scanners log a missing echo as a fixed out-of-range number, not as inf:

    1. SICK LMS codes: everything from :data:`SICK_NO_RETURN_M` (81 m) up, since the
       scanner cannot measure beyond 80 m; this covers 81.83 (Intel) and 81.91 (MIT, fr079).
    2. Otherwise a driver's max-range fill (e.g. 50 m): the log's largest reading ``L``
       when ``L >= 20 m`` and it repeats (at least twice and on at least 0.1 % of all
       readings) - a real wall at exactly the farthest distance seen does not recur like a
       saturated value. Readings equal to ``L`` are then "no return" too.
    3. Otherwise no reading is treated as "no return".
    """
    values = np.asarray(ranges, dtype=float).reshape(-1)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return math.inf
    top = float(values.max())
    if top >= SICK_NO_RETURN_M:
        return SICK_NO_RETURN_M
    repeats = int(np.count_nonzero(values == top))
    if top >= MIN_FILL_VALUE_M and repeats >= max(2, 1e-3 * values.size):
        return top
    return math.inf


def range_limit(threshold: float, ranges: np.ndarray) -> float:
    """Return ``range_max`` for a log: 1 mm below the no-return value, else its longest reading.

    Readings above ``range_max`` are turned into +inf by :func:`clean_ranges`, so a reading
    exactly equal to the no-return value is "no return" and ``range_max`` stays a length
    the scanner can actually report (the logs have 1 cm resolution).
    """
    if math.isfinite(threshold):
        return threshold - 1e-3
    finite = np.asarray(ranges, dtype=float)
    finite = finite[np.isfinite(finite)]
    return float(finite.max()) if finite.size else SICK_NO_RETURN_M - 1e-3


def clean_ranges(ranges: np.ndarray, range_max: float) -> np.ndarray:
    """Return ranges with "no return" readings as +inf and non-positive ones as NaN.

    REP-117: +inf is "no return within range", NaN an erroneous reading; CARMEN drivers
    write 0 or negative numbers only on errors.
    """
    r = np.array(ranges, dtype=float)
    with np.errstate(invalid='ignore'):
        r[r > range_max] = np.inf
        r[r <= 0.0] = np.nan
    return r


def seconds_to_ns(seconds: np.ndarray) -> np.ndarray:
    """Convert logged seconds to integer nanoseconds, rounded to the logs' microseconds.

    CARMEN prints stamps with 6 decimals; a float64 near 1.1e9 s carries about 0.2 us of
    error, so rounding to whole microseconds recovers the printed value exactly.
    """
    t = np.asarray(seconds, dtype=float)
    return np.round(t * 1e6).astype(np.int64) * 1000


def longest_increasing(stamps: np.ndarray, strict: bool = True) -> np.ndarray:
    """Return a mask of a longest (strictly or non-strictly) increasing subsequence.

    Patience sorting, O(n log n): keeping the longest ordered subsequence drops the fewest
    samples, so a single stamp that jumps too far forward or backward costs one sample
    instead of every sample until the clock catches up.
    """
    values = np.asarray(stamps).tolist()
    find = bisect.bisect_left if strict else bisect.bisect_right
    tails: list = []
    tail_index: list[int] = []
    parent = [-1] * len(values)
    for i, value in enumerate(values):
        k = find(tails, value)
        if k < len(tails) and tails[k] == value:
            continue  # strict run: keep the earliest sample of a repeated stamp
        if k == len(tails):
            tails.append(value)
            tail_index.append(i)
        else:
            tails[k] = value
            tail_index[k] = i
        parent[i] = tail_index[k - 1] if k > 0 else -1
    mask = np.zeros(len(values), dtype=bool)
    i = tail_index[-1] if tail_index else -1
    while i >= 0:
        mask[i] = True
        i = parent[i]
    return mask


def repair_scan_stamps(stamps_ns: np.ndarray) -> tuple[np.ndarray, int]:
    """Return strictly increasing scan stamps and how many were changed.

    The file order is trusted as the acquisition order (the odometry stored with each
    scan advances in that order); the clock is what jitters. Stamps outside a longest
    non-decreasing subsequence are re-estimated by linear interpolation over the scan
    index between their kept neighbours, and then every stamp is raised to at least
    :data:`MIN_STAMP_STEP_NS` after its predecessor. The second step is
    ``t'_i = max_{j<=i}(t_j - j s) + i s``: the smallest sequence with steps >= s that
    never lowers a stamp. No scan is dropped.
    """
    t = np.asarray(stamps_ns, dtype=np.int64)
    n = t.shape[0]
    if n < 2 or bool(np.all(np.diff(t) > 0)):
        return t.copy(), 0
    keep = longest_increasing(t, strict=False)
    index = np.arange(n)
    fixed = t.copy()
    if not keep.all():
        estimate = np.interp(index[~keep], index[keep], t[keep].astype(float))
        fixed[~keep] = np.round(estimate).astype(np.int64)
    offset = index.astype(np.int64) * MIN_STAMP_STEP_NS
    fixed = np.maximum.accumulate(fixed - offset) + offset
    return fixed, int(np.count_nonzero(fixed != t))


def increasing_trajectory(stamps_ns: np.ndarray, poses: np.ndarray,
                          path: Path | str, what: str) -> Trajectory:
    """Return a trajectory of the samples along a longest strictly increasing stamp run.

    Used for pose streams (odometry), where a sample with a duplicate or out-of-order
    stamp adds nothing reliable: it is dropped (and counted in a warning) rather than
    re-stamped, so no stamp in a pose stream is invented.
    """
    t = np.asarray(stamps_ns, dtype=np.int64)
    p = np.asarray(poses, dtype=float).reshape(-1, 3)
    if t.shape[0] > 1 and not bool(np.all(np.diff(t) > 0)):
        keep = longest_increasing(t, strict=True)
        LOGGER.warning('%s: dropped %d of %d %s samples with duplicate or out-of-order stamps',
                       path, int(np.count_nonzero(~keep)), t.shape[0], what)
        t, p = t[keep], p[keep]
    p = p.copy()
    p[:, 2] = se2.wrap_angle(p[:, 2])
    return Trajectory(t, p)


def make_scans(ranges: list[np.ndarray], stamps_ns: np.ndarray,
               geometry: list[tuple[float, float, float]], range_max: float,
               frame_id: str = 'laser') -> list[LaserScan]:
    """Build one :class:`LaserScan` per row (``range_min`` 0, no-return readings as +inf)."""
    return [LaserScan(stamp_ns=int(stamp), angle_min=geo[0], angle_max=geo[1],
                      angle_increment=geo[2], range_min=0.0, range_max=range_max,
                      ranges=clean_ranges(r, range_max), frame_id=frame_id)
            for r, stamp, geo in zip(ranges, stamps_ns, geometry)]
