"""De-skewing: a scan swept while the robot moved, moved to the instant of its stamp.

A rotating lidar measures beam ``i`` at ``t_i = i * time_increment`` after the first
beam, so during a turn the end of the sweep is seen from another pose than its start
and the scan is bent. With the robot's twist ``xi = (v_x, v_y, omega)`` (base frame,
constant over the short sweep), the base at time ``t`` is ``exp(t xi)`` relative to the
base at the stamp, and a point ``p_i`` seen at ``t_i`` lies at

    ``p_i' = exp(t_i xi) p_i = R(omega t_i) p_i + V(omega t_i) v t_i``

in the base frame of the stamp, where ``V(theta) = [[sin th, cos th - 1],
[1 - cos th, sin th]] / th`` is the left Jacobian of SO(2) (the SE(2) exponential; e.g.
Barfoot, "State Estimation for Robotics", sec. 7.1.9). The stamp is the instant the
published pose belongs to: the first beam's time (the ROS convention for
``sensor_msgs/LaserScan``) or, with ``scan_stamp: last_beam``, the last beam's.

The twist comes from the motion prediction and is then refined by the match itself
(de-skew, match, re-estimate, de-skew again; see
:class:`laser_odom.core.pipeline.odometry.OdometryPipeline`), as KISS-ICP does with the
constant-velocity model (Vizzo et al., RA-L 2023, sec. III-A).
"""

from __future__ import annotations

import math

import numpy as np

from laser_odom.core import se2
from laser_odom.core.events import EventLog
from laser_odom.core.scan.laser_scan import LaserScan, ScanPoints

SWEEP_TOLERANCE = 0.05
"""A sweep may last up to this fraction longer than ``scan_time`` (driver rounding)."""

MAX_SWEEP_WITHOUT_SCAN_TIME = 1.0
"""Longest believable sweep [s] when ``scan_time`` cannot check it (a 1 Hz lidar)."""

DESKEW_EVENTS = {
    'time_increment_repaired': 'time_increment is 0 but deskew is on: taken as '
                               'scan_time / beams per revolution',
    'time_increment_reversed': 'time_increment is negative: the beams were taken from '
                               'the last to the first (a reversed sweep)',
    'time_increment_invalid': 'time_increment is NaN, inf or longer than the scan',
    'sweep_timing_missing': 'deskew is on but the scan has neither time_increment nor '
                            'scan_time: the scan is not de-skewed',
}
"""Counted (and said once) when a scan's sweep timing is repaired or ignored."""


def beam_times(count: int, time_increment: float, stamp_at_last: bool) -> np.ndarray:
    """Return each beam's time [s] relative to the scan stamp.

    A negative ``time_increment`` is a sweep from the last beam to the first. The stamp
    belongs to the first beam measured, or with ``stamp_at_last`` to the last.
    """
    step = abs(time_increment)
    order = np.arange(count) if time_increment >= 0.0 else np.arange(count)[::-1]
    times = order * step
    if stamp_at_last:
        times = times - (count - 1) * step
    return times


def sweep_times(scan: LaserScan, count: int, mode: str, stamp_at_last: bool,
                events: EventLog, last_valid: float | None = None) -> np.ndarray | None:
    """Return the beam times of a scan for de-skewing, or None when it is not de-skewed.

    ``mode`` is the ``deskew`` parameter: ``off``; ``auto`` de-skews the scans that
    carry a non-zero ``time_increment``; ``on`` also repairs a zero one from
    ``scan_time`` (one revolution per scan). Timing that cannot be right - NaN, or a
    sweep longer than the scan period - is counted and said once; the scan then takes
    ``last_valid``, the ``time_increment`` of the last scan of the same beam count
    that had a valid one (the same sensor: leaving one scan bent among straight ones
    would bias the two matches it takes part in), or is not de-skewed without one.
    """
    if mode == 'off':
        return None
    increment, scan_time = scan.time_increment, scan.scan_time
    if not isinstance(increment, (int, float)) or not math.isfinite(increment):
        return _invalid(events, '', count, last_valid, stamp_at_last)
    period = float(scan_time) if isinstance(scan_time, (int, float)) and math.isfinite(
        scan_time) and scan_time > 0.0 else 0.0
    if increment == 0.0:
        if mode != 'on':
            return None
        if period == 0.0:
            events.warn('sweep_timing_missing', DESKEW_EVENTS['sweep_timing_missing'],
                        once=True)
            return None
        increment = period * abs(scan.angle_increment) / (2.0 * math.pi)
        events.warn('time_increment_repaired', DESKEW_EVENTS['time_increment_repaired'],
                    once=True)
    sweep = abs(increment) * (count - 1)
    limit = period * (1.0 + SWEEP_TOLERANCE) if period > 0.0 else MAX_SWEEP_WITHOUT_SCAN_TIME
    if sweep > limit:
        return _invalid(events, f' (sweep {sweep:.3g} s, scan_time {period:.3g} s)', count,
                        last_valid, stamp_at_last)
    if increment < 0.0:
        events.warn('time_increment_reversed', DESKEW_EVENTS['time_increment_reversed'],
                    once=True)
    return beam_times(count, increment, stamp_at_last)


def twist_of_step(step: np.ndarray, dt: float) -> np.ndarray:
    """Return the constant twist ``log(step) / dt`` that moves the base by ``step`` in ``dt``.

    ``step`` is ``(x, y, theta)`` in the base frame at the start; the translation of
    the logarithm is ``V(theta)^-1 (x, y)`` (the inverse of :func:`move_points`' V).
    Zero for ``dt <= 0`` or a non-finite step.
    """
    step = np.asarray(step, dtype=float)
    if not dt > 0.0 or not np.all(np.isfinite(step)):
        return np.zeros(3)
    theta = float(step[2])
    if abs(theta) < 1e-6:
        a, b = 1.0 - theta ** 2 / 6.0, theta / 2.0
    else:
        a, b = math.sin(theta) / theta, (1.0 - math.cos(theta)) / theta
    norm = a * a + b * b
    vx = (a * step[0] + b * step[1]) / norm
    vy = (-b * step[0] + a * step[1]) / norm
    return np.array([vx, vy, theta]) / dt


def step_of_twist(twist: np.ndarray, dt: float) -> np.ndarray:
    """Return the step ``exp(dt xi)`` a constant twist moves the base by in ``dt``.

    The inverse of :func:`twist_of_step`: ``(V(omega dt) v dt, omega dt)``, the motion
    :func:`move_points` applies to the base's origin.
    """
    twist = np.asarray(twist, dtype=float)
    moved = move_points(np.zeros((1, 2)), np.array([float(dt)]), twist)[0]
    return np.array([moved[0], moved[1], float(twist[2]) * dt])


def _invalid(events: EventLog, detail: str, count: int, last_valid: float | None,
             stamp_at_last: bool) -> np.ndarray | None:
    """Count and say (once) unusable timing; fall back on the last valid increment."""
    fallback = ('; the last valid time_increment is used' if last_valid is not None else
                '; the scan is not de-skewed')
    events.warn('time_increment_invalid', DESKEW_EVENTS['time_increment_invalid'] + detail
                + fallback, once=True)
    return None if last_valid is None else beam_times(count, last_valid, stamp_at_last)


def move_points(points: np.ndarray, times: np.ndarray, twist: np.ndarray) -> np.ndarray:
    """Return ``exp(t_i xi) p_i`` for every point: each moved to the stamp's base frame.

    ``points`` (N, 2) and ``times`` (N,) [s]; ``twist`` is ``(v_x, v_y, omega)`` in the
    base frame [m/s, rad/s]. Vectorised; the series of ``V`` is used near ``theta = 0``.
    """
    theta = twist[2] * times
    c, s = np.cos(theta), np.sin(theta)
    small = np.abs(theta) < 1e-6
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta ** 2 / 6.0, s / safe)          # sin(th) / th
    b = np.where(small, theta / 2.0, (1.0 - c) / safe)             # (1 - cos th) / th
    vx, vy = twist[0] * times, twist[1] * times
    x, y = points[:, 0], points[:, 1]
    return np.column_stack((c * x - s * y + a * vx - b * vy,
                            s * x + c * y + b * vx + a * vy))


def sweep_shift(times: np.ndarray, ranges: np.ndarray, twist_change: np.ndarray) -> float:
    """Return a bound [m] on how far points move when the twist changes by ``twist_change``.

    Over the longest beam time a point at range ``r`` moves by at most
    ``|t| (|dv| + |domega| r)`` more: the test of whether re-de-skewing is worth a
    second match.
    """
    if times.size == 0:
        return 0.0
    t = float(np.max(np.abs(times)))
    r = float(np.max(ranges)) if ranges.size else 0.0
    return t * (math.hypot(twist_change[0], twist_change[1]) + abs(twist_change[2]) * r)


SWEEP_LEAD = 0.875
"""Steps from the middle of a measured step to the middle of the next sweep, for a scan
stamped at its first beam: half a step, then half of a sweep lasting three quarters of
the period (a 270 deg scanner). Taken for every scanner: the middle of the beam times of
the points that returned (about a whole step under the 360 deg RPLidar A1) measured
worse in the simulated fast hall (nicp and imls, 50 m drift 0.5-0.7 % -> 0.8-1.4 %),
and so did their median (nicp 0.7 -> 1.8 %)."""


class SweepTwist:
    """The twist a scan is de-skewed with once its match measured the step's.

    A match measures the twist of the step from the reference's stamp to the current
    one, an interval centred half a step before the current stamp. A scan stamped at
    its first beam is swept *after* its stamp, so when the robot starts or ends a turn
    the measured twist lags the one over the sweep: at 1.5 rad/s reached within a
    second, by a few tenths of a rad/s, which bends a wall 20 m away by decimetres. The
    twist is extrapolated linearly from the change since the previous scan's
    measurement, :data:`SWEEP_LEAD` steps ahead: ``w + (w - w_prev) lead dt / (t -
    t_prev)``. A scan stamped at its last beam is swept before its stamp, and the lead
    is an eighth of a step.

    Three choices, each measured against its alternative:

    - both twists are first measurements, each from a match whose scans were de-skewed
      with the prediction; differencing the final twists (matched after de-skewing with
      an extrapolated one) drove the simulated slow hall's 50 m drift from 1.7 to 11 %
      (nicp);
    - it is used only when the measured twist moves the points by more than
      :data:`.pipeline.odometry.DESKEW_TOLERANCE` (``changed``: the scan is matched
      again anyway); in steady motion consecutive twists differ by their noise, which
      extrapolating would double;
    - a component is extrapolated past zero too: stopping it there (a turn ending at
      rest) made the fast worlds' drift worse (nicp 0.7 -> 2.9-4.3 %), since a
      component near zero (the lateral speed, the turn rate on a straight) changes sign
      with its noise.

    Scan to scan only: there the reference scan is de-skewed again with the same measured
    twist, so a twist that is off bends both scans alike and the match hardly moves.
    The local map is not de-skewed again; the measured twist then carries the current
    scan's de-skew error, and extrapolating it diverged within 30 scans (the simulated
    slow hall, nicp: 50 m drift 0.6 -> 109 %). A step against the map is the difference
    of two poses each anchored on the map, so it carries minus the previous pose's
    error, and the extrapolation feeds that error back: the fast hall diverged with a
    lead of 0.3 and 0.5 too (drift 15-94 %); :class:`MidSweepTwist` is used there
    instead. Measured against the map and not taken
    (3 seeds of the fast hall and campus, plicp, nicp and imls, mixed or worse):
    keeping the newest scan out of the map until the next match measures its sweep;
    extrapolating the twist of a second match against the previous scan instead
    (imls hall 0.2-0.6 %, but nicp campus 10-17 % and plicp worse everywhere); taking
    the step from that match, made again as scan to scan does, whenever the de-skew
    matters (nicp hall failed steps 14 -> 3, but one nicp campus seed drifted 32 %);
    the twist corrected by matching the two halves of the sweep on their own (noisier
    than the measured twist).
    """

    def __init__(self) -> None:
        """Start without a previous measurement."""
        self.forget()

    def forget(self) -> None:
        """Drop the previous measurement (the pipeline was reset)."""
        self._previous: tuple[int, np.ndarray] | None = None

    def over_sweep(self, measured: np.ndarray, clock_ns: int, step_dt: float,
                   sweeps_after_stamp: bool, changed: bool) -> np.ndarray:
        """Return the twist to de-skew the scan at ``clock_ns`` with, and record ``measured``.

        ``step_dt`` [s] is the measured step's interval; ``clock_ns`` the scan's time on
        the same clock (the pipeline's sum of such intervals: the stamp of a regular
        stream, but bursty logger stamps 1 ms apart would extrapolate 200-fold);
        ``sweeps_after_stamp`` tells whether the scan is stamped at its first beam.
        """
        measured = np.asarray(measured, dtype=float)
        previous, self._previous = self._previous, (clock_ns, measured)
        if not changed or previous is None:
            return measured
        span = (clock_ns - previous[0]) * 1e-9
        if not span > 0.0:
            return measured
        lead = SWEEP_LEAD if sweeps_after_stamp else 1.0 - SWEEP_LEAD
        return measured + (measured - previous[1]) * (lead * step_dt / span)


MID_SWEEP_WEIGHT = 0.5
"""Weight of the twist between mid-sweep poses against the measured step's twist when
de-skewing against the local map (:class:`MidSweepTwist`)."""


class MidSweepTwist:
    """The twist a scan is de-skewed with against the local map.

    Against the map each pose is anchored on the map, and a match absorbs a de-skew
    twist that is off by ``e`` as a rotation and shift of the cloud about its mean beam
    time ``t_m``: the pose at the stamp is off by ``-t_m e``. The measured step, the
    difference of two such poses, then carries ``e`` back into the next de-skew:
    ``e_k+1 = -(t_m / T)(e_k - e_k-1)`` for steps of ``T``, a mode at ``z = -1`` when
    the sweep fills the period (``t_m = T / 2``, a 360 deg lidar). In the simulated fast
    hall (360 deg at 5 Hz) the de-skew twist alternated by up to 0.38 rad/s about the
    true zero while the robot drove straight; de-skewed with the true twist, the same
    map drifted 0.07-0.10 % instead of 1.7-17 %. A scan-to-scan reference has no such
    loop: it is de-skewed again with the same measured twist.

    The pose at the middle of the sweep, ``pose exp(t_m xi)`` with the twist ``xi`` the
    scan was matched with, does not carry ``e`` to first order (CT-ICP, Dellenbach et
    al., ICRA 2022, likewise poses a scan within its sweep, at its start and end,
    rather than at one instant). So the twist between consecutive mid-sweep poses has
    no loop, but lags the sweep by half a step and carries both poses' noise. After its
    first match a scan is de-skewed with the mean of it and the measured twist
    (:data:`MID_SWEEP_WEIGHT`, :meth:`blended`), which halves the loop's gain; the next
    scan is de-skewed with that same twist before its first match, in place of the
    constant-velocity prediction's, the last matched step's (:meth:`predicted`).

    Measured with nicp, imls and plicp in the simulated hall and campus, against the
    map (3 seeds, 3 copies with 1 mm of range noise each; failed steps, then the
    matchers' median 50 m drift), before -> after:

    - fast hall (360 deg lidar): 123 -> 4 failed, drift 3.3-5.3 % -> 0.10-0.21 %;
    - fast campus (270 deg): 83 -> 5 failed (plicp), drift 0.6-2.1 % -> 0.2-0.7 %;
    - slow hall: plicp drift 3.4 -> 0.07 %, nicp and imls 0.3 -> 0.1 %; slow campus
      0.06-0.14 -> 0.04 %; none failed before or after;
    - the de-skew grid's 5 Hz 360 deg lidars (LDS-01, RPLidar A1; the 270 deg and
      faster ones unchanged): 40 -> 11 failed.

    Each half measured alone: after the first match only, fast hall 31 failed and fast
    campus 101; the twist between mid-sweep poses alone, without the measured one, 50
    and 160. Weights of 0.25 and 0.75 were each worse than 0.5 somewhere. Extrapolating
    the twist ahead, as :class:`SweepTwist` does scan to scan, diverged.
    """

    def __init__(self) -> None:
        """Start without a previous mid-sweep pose."""
        self.forget()

    def forget(self) -> None:
        """Drop the previous mid-sweep pose (a reset, a rejected match)."""
        self._previous: tuple[int, np.ndarray] | None = None
        self._last: np.ndarray | None = None

    def predicted(self, prediction: np.ndarray) -> np.ndarray:
        """Return the twist to de-skew the next scan with before its first match.

        The constant-velocity prediction's twist is the last matched step's, which
        carries the de-skew error of the two map-anchored poses it joins; the last
        scan's blended twist (:meth:`blended`) carries half of it. Without one (the
        first scans, after a rejection), ``prediction``.
        """
        return prediction if self._last is None else self._last.copy()

    def blended(self, measured: np.ndarray, pose: np.ndarray, scan: ScanPoints,
                clock_ns: int) -> np.ndarray:
        """Return the twist to de-skew ``scan`` with, and record its mid-sweep pose.

        ``pose`` is the scan's matched pose at its stamp (odometry frame), with its
        points de-skewed by ``scan.twist``; ``measured`` is the matched step's twist.
        ``clock_ns`` is the scan's time on the clock the steps are measured on (as
        :meth:`SweepTwist.over_sweep`). Without a previous mid-sweep pose, ``measured``.
        """
        measured = np.asarray(measured, dtype=float)
        if scan.times is None or len(scan.times) == 0:
            self.forget()
            return measured
        used = np.zeros(3) if scan.twist is None else np.asarray(scan.twist, dtype=float)
        middle = se2.compose(pose, step_of_twist(used, float(np.mean(scan.times))))
        previous, self._previous = self._previous, (clock_ns, middle)
        if previous is None:
            return measured
        span = (clock_ns - previous[0]) * 1e-9
        if not span > 0.0:
            return measured
        between = twist_of_step(se2.relative(previous[1], middle), span)
        self._last = MID_SWEEP_WEIGHT * between + (1.0 - MID_SWEEP_WEIGHT) * measured
        return self._last.copy()


def sweeps_after_stamp(scan: ScanPoints) -> bool:
    """Tell whether the scan was swept after its stamp (stamped at its first beam)."""
    return scan.times is not None and float(np.median(scan.times)) > 0.0


def deskewed(scan: ScanPoints, twist: np.ndarray) -> ScanPoints:
    """Return the scan's points moved to the stamp by ``twist``.

    The result is a new object: caches of normals and search indices belong to the old
    points. A scan without beam times is returned as it is.
    """
    if scan.times is None:
        return scan
    measured = scan.points if scan.measured is None else scan.measured
    with np.errstate(over='ignore', invalid='ignore'):
        moved = move_points(measured, scan.times, np.asarray(twist, dtype=float))
    if not np.all(np.isfinite(moved)):  # an absurd twist: keep the scan as measured
        moved = measured
    return ScanPoints(moved, scan.beam_index, scan.ranges, scan.stamp_ns, times=scan.times,
                      measured=measured, twist=np.asarray(twist, dtype=float))


def deskew_change(scan: ScanPoints, twist: np.ndarray) -> float:
    """Return how far [m, bound] de-skewing with ``twist`` instead would move the points."""
    if scan.times is None:
        return 0.0
    used = np.zeros(3) if scan.twist is None else scan.twist
    return sweep_shift(scan.times, scan.ranges, np.asarray(twist, dtype=float) - used)
