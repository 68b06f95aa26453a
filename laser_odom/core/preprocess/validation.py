"""Scan validation before matching: every rejected scan gets a named reason.

A sensor driver, a bag or a simulator can hand over anything: NaN angles, a zero
increment, more ranges than the angle fields announce, inverted range limits. Each
check below either rejects the scan with a reason (counted, and said in a throttled
warning) or repairs what can be repaired and says so once. Beam count, field of view
and frame may change from one scan to the next; every scan is judged on its own. The
sweep timing (``time_increment``, ``scan_time``) is judged by
:func:`laser_odom.core.preprocess.deskew.sweep_times`.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from laser_odom.core.configuration.pipeline import MountingConfig, ScanConfig
from laser_odom.core.events import EventLog
from laser_odom.core.preprocess.deskew import sweep_times
from laser_odom.core.scan.laser_scan import LaserScan, scan_to_points, ScanPoints

SPAN_TOLERANCE = 1e-3
"""Slack [rad] on the 2 pi limit of a scan's angular span (float rounding of drivers)."""

REJECTIONS = {
    'empty_scan': 'scan has no ranges',
    'bad_ranges': 'ranges are not a list of numbers',
    'non_finite_angles': 'angle_min, angle_max or angle_increment is NaN or inf',
    'zero_increment': 'angle_increment is zero',
    'span_over_2pi': 'the scan spans more than 2 pi',
    'too_few_points': 'fewer valid readings than min_valid_points',
}
"""Reasons a scan is skipped, with what they mean."""


class ScanValidator:
    """Checks a scan's fields and converts it to base-frame points."""

    def __init__(self, scan_config: ScanConfig, mounting: MountingConfig,
                 events: EventLog | None = None) -> None:
        """Create the validator; rejections and repairs are reported to ``events``."""
        self.config = scan_config
        self.mounting = mounting.mounting()
        self.events = events if events is not None else EventLog()
        self._valid_increments: dict[int, float] = {}
        """The last valid ``time_increment`` per beam count (the fallback for bad ones)."""

    def thin(self, scan: LaserScan) -> LaserScan:
        """Return ``scan`` on every k-th beam when it has more than ``max_beams``.

        The matchers' cost grows with the points (the global search refines each
        candidate on all of them), so a scan of 20,000 beams would hold a live node for
        tens of seconds. Every k-th beam keeps an ordered scan with a k times wider
        ``angle_increment`` and ``time_increment`` (the same sweep, the same field of
        view), which every matcher and the de-skewing read unchanged. Malformed fields
        are left for :meth:`check` to judge.
        """
        limit = self.config.max_beams
        try:
            count = len(scan.ranges)
        except TypeError:
            return scan
        if limit <= 0 or count <= limit:
            return scan
        step = -(-count // limit)
        self.events.warn(
            'scan_thinned', f'scans have {count} beams, more than max_beams ({limit}): '
            f'one beam in {step} is matched', once=True)
        increment = scan.time_increment
        timed = isinstance(increment, (int, float))
        # The beam the stamp belongs to is kept, so the sweep times stay exact.
        stamped_last = (self.config.scan_stamp == 'last_beam') != (timed and increment < 0)
        first = (count - 1) % step if stamped_last else 0
        intensities = scan.intensities
        if intensities is not None and len(intensities) == count:
            intensities = intensities[first::step]
        return dataclasses.replace(
            scan, ranges=scan.ranges[first::step], intensities=intensities,
            angle_min=scan.angle_min + first * scan.angle_increment,
            angle_increment=scan.angle_increment * step,
            time_increment=increment * step if timed else increment)

    def check(self, scan: LaserScan) -> tuple[ScanPoints | None, str]:
        """Return ``(points, '')`` for a usable scan or ``(None, reason)``."""
        try:
            ranges = np.asarray(scan.ranges, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            return None, 'bad_ranges'
        if ranges.size == 0:
            return None, 'empty_scan'
        angles = (scan.angle_min, scan.angle_max, scan.angle_increment)
        if not all(isinstance(a, (int, float)) and math.isfinite(a) for a in angles):
            return None, 'non_finite_angles'
        if scan.angle_increment == 0.0:
            return None, 'zero_increment'
        span = abs(scan.angle_increment) * (ranges.size - 1)
        if span > 2.0 * math.pi + SPAN_TOLERANCE or abs(
                scan.angle_max - scan.angle_min) > 2.0 * math.pi + SPAN_TOLERANCE:
            return None, 'span_over_2pi'
        self._check_length(scan, ranges.size)
        range_min, range_max = self._range_limits(scan)
        self._check_intensities(scan, ranges.size)
        usable = LaserScan(scan.stamp_ns, scan.angle_min, scan.angle_max,
                           scan.angle_increment, range_min, range_max, ranges,
                           None, scan.frame_id)
        points = scan_to_points(usable, self.mounting)
        if len(points) < self.config.min_valid_points:
            return None, 'too_few_points'
        invalid_before = self.events.counters['time_increment_invalid']
        times = sweep_times(scan, ranges.size, self.config.deskew,
                            self.config.scan_stamp == 'last_beam', self.events,
                            self._valid_increments.get(ranges.size))
        if times is not None:
            points.times = times[points.beam_index]
            if self.events.counters['time_increment_invalid'] == invalid_before and (
                    scan.time_increment):
                self._valid_increments[ranges.size] = float(scan.time_increment)
        return points, ''

    def _check_length(self, scan: LaserScan, count: int) -> None:
        """Warn once when ``ranges`` disagrees with the angle fields; the ranges win."""
        expected = (scan.angle_max - scan.angle_min) / scan.angle_increment + 1.0
        if abs(expected - count) > 1.0:
            self.events.warn(
                'length_mismatch',
                f'scan has {count} ranges but its angle fields describe {expected:.0f} '
                'beams; using the ranges with angle_min and angle_increment', once=True)

    def _range_limits(self, scan: LaserScan) -> tuple[float, float]:
        """Return usable range limits; bad ones fall back to the readings (warn once)."""
        low, high = scan.range_min, scan.range_max
        valid = (isinstance(low, (int, float)) and isinstance(high, (int, float))
                 and not math.isnan(low) and not math.isnan(high)
                 and low >= 0.0 and high > 0.0 and low < high)
        if valid:
            return float(low), float(high)
        self.events.warn(
            'bad_range_limits',
            f'scan range_min={low!r} range_max={high!r} are NaN, negative or inverted; '
            'using every finite positive reading', once=True)
        return 1e-9, math.inf

    def _check_intensities(self, scan: LaserScan, count: int) -> None:
        """Warn once when the intensities do not match the ranges (they are not used)."""
        intensities = scan.intensities
        if intensities is not None and len(intensities) not in (0, count):
            self.events.warn(
                'intensities_length',
                f'scan has {len(intensities)} intensities for {count} ranges; '
                'intensities are ignored', once=True)
