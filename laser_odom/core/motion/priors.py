"""External motion priors buffered by time: wheel odometry motion and IMU yaw change.

Wheel odometry and IMU messages arrive at their own rates, slightly out of step with
the scans. At each scan the pipeline wants the motion since the previous processed
scan (``OdometryPipeline.process(scan, prior_step, prior_yaw)``). These buffers keep a
bounded history and answer by linear interpolation between the samples around each
stamp; a scan a little newer than the newest sample (a prior message still in flight)
is served by extrapolating the last sample's rate for at most
``prior_max_extrapolation`` seconds. Beyond that, or before the oldest sample, the
prior is *stale* and the answer is None, so the pipeline falls back to constant
velocity and counts ``prior_missing``.

Both the ROS node and the replay harness (``--prior odom``) use these classes, so a
prior is judged identically live and offline.
"""

from __future__ import annotations

from collections import deque
import math
from typing import Any

import numpy as np

from laser_odom.core import se2
from laser_odom.core.configuration.node import PriorConfig
from laser_odom.core.trajectory import ImuSamples, Trajectory

MAX_SAMPLES = 100000
"""Hard cap on buffered samples, whatever the message rate (memory bound)."""


class _TimedBuffer:
    """Samples ``(stamp_ns, row)`` in increasing stamp order, bounded in time and count."""

    def __init__(self, config: PriorConfig | None = None) -> None:
        """Create an empty buffer."""
        self.config = config if config is not None else PriorConfig()
        self._samples: deque[tuple[int, tuple[float, ...]]] = deque(maxlen=MAX_SAMPLES)
        self._arrays: tuple[np.ndarray, np.ndarray] | None = None
        self.time_jumps = 0

    def __len__(self) -> int:
        """Return the number of buffered samples."""
        return len(self._samples)

    @property
    def newest_ns(self) -> int | None:
        """Stamp of the newest sample, or None when empty."""
        return self._samples[-1][0] if self._samples else None

    def clear(self) -> None:
        """Forget every sample."""
        self._samples.clear()
        self._arrays = None

    def _add_row(self, stamp_ns: int, row: tuple[float, ...]) -> None:
        """Append a sample; a stamp older than the newest means time jumped back."""
        stamp_ns = int(stamp_ns)
        newest = self.newest_ns
        if newest is not None and stamp_ns <= newest:
            if stamp_ns == newest:
                return
            self.time_jumps += 1
            self._samples.clear()
        self._samples.append((stamp_ns, row))
        horizon = stamp_ns - int(self.config.prior_buffer_duration * 1e9)
        while len(self._samples) > 2 and self._samples[1][0] <= horizon:
            self._samples.popleft()
        self._arrays = None

    def _data(self) -> tuple[np.ndarray, np.ndarray]:
        """Return stamps (N,) and rows (N, k) as arrays, cached until the next add."""
        if self._arrays is None:
            stamps = np.fromiter((s for s, _ in self._samples), dtype=np.int64,
                                 count=len(self._samples))
            rows = np.array([r for _, r in self._samples], dtype=float)
            self._arrays = stamps, rows.reshape(len(self._samples), -1)
        return self._arrays

    def _covered(self, stamp_ns: int) -> bool:
        """Tell whether a stamp is inside the buffer or within the extrapolation limit."""
        if not self._samples:
            return False
        first, last = self._samples[0][0], self._samples[-1][0]
        limit = int(self.config.prior_max_extrapolation * 1e9)
        return first <= stamp_ns <= last + limit


class OdometryBuffer(_TimedBuffer):
    """Wheel odometry poses ``[x, y, yaw]`` of the base (any fixed odometry frame)."""

    def add(self, stamp_ns: int, pose: se2.Pose) -> None:
        """Buffer one odometry pose."""
        self._add_row(stamp_ns, (float(pose[0]), float(pose[1]), float(pose[2])))

    def pose_at(self, stamp_ns: int) -> se2.Pose | None:
        """Return the interpolated (or briefly extrapolated) pose at a stamp, or None."""
        if not self._covered(stamp_ns):
            return None
        stamps, poses = self._data()
        if stamp_ns <= stamps[-1]:
            return Trajectory(stamps, poses).interpolate(stamp_ns)
        if len(stamps) < 2:
            return None
        # Extrapolate the last step's body-frame motion (constant twist over the gap).
        step = se2.relative(poses[-2], poses[-1])
        fraction = (stamp_ns - stamps[-1]) / max(int(stamps[-1] - stamps[-2]), 1)
        return se2.compose(poses[-1], step * fraction)

    def motion_between(self, start_ns: int, end_ns: int) -> se2.Pose | None:
        """Return the base motion from ``start_ns`` to ``end_ns`` in the start frame."""
        start, end = self.pose_at(start_ns), self.pose_at(end_ns)
        if start is None or end is None:
            return None
        return se2.relative(start, end)


class ImuBuffer(_TimedBuffer):
    """IMU yaw (from orientation, when the IMU provides one) and yaw rate about z.

    The IMU's z axis is assumed parallel to the base's (REP-145 body frame, mounted
    level and upright), so its yaw change is the base's yaw change.
    """

    def add(self, stamp_ns: int, yaw: float | None, yaw_rate: float) -> None:
        """Buffer one IMU sample; ``yaw`` is None when orientation is not provided."""
        self._add_row(stamp_ns, (math.nan if yaw is None else float(yaw), float(yaw_rate)))

    def yaw_change(self, start_ns: int, end_ns: int) -> float | None:
        """Return the yaw change from ``start_ns`` to ``end_ns``, or None when stale.

        From orientation when every sample in the interval carries one, otherwise by
        integrating the piecewise-linear yaw rate (trapezoidal rule).
        """
        if not (self._covered(start_ns) and self._covered(end_ns)):
            return None
        stamps, rows = self._data()
        lo = max(int(np.searchsorted(stamps, start_ns, side='right')) - 1, 0)
        hi = min(int(np.searchsorted(stamps, end_ns, side='left')) + 1, len(stamps))
        yaws = rows[lo:hi, 0]
        if np.all(np.isfinite(yaws)):
            return float(se2.wrap_angle(
                self._yaw_at(stamps[lo:hi], yaws, rows[lo:hi, 1], end_ns)
                - self._yaw_at(stamps[lo:hi], yaws, rows[lo:hi, 1], start_ns)))
        return self._rate_integral(stamps, rows[:, 1], end_ns) - self._rate_integral(
            stamps, rows[:, 1], start_ns)

    @staticmethod
    def _yaw_at(stamps: np.ndarray, yaws: np.ndarray, rates: np.ndarray,
                stamp_ns: int) -> float:
        """Return the unwrapped orientation yaw at a stamp (rate-extrapolated past the end)."""
        unwrapped = np.unwrap(yaws)
        if stamp_ns > stamps[-1]:
            return float(unwrapped[-1] + rates[-1] * (stamp_ns - stamps[-1]) * 1e-9)
        return float(np.interp(stamp_ns, stamps, unwrapped))

    @staticmethod
    def _rate_integral(stamps: np.ndarray, rates: np.ndarray, stamp_ns: int) -> float:
        """Return the integral of the yaw rate from the first sample to ``stamp_ns``."""
        t = (stamps - stamps[0]) * 1e-9
        cumulative = np.concatenate(([0.0], np.cumsum(0.5 * (rates[1:] + rates[:-1])
                                                      * np.diff(t))))
        x = (stamp_ns - stamps[0]) * 1e-9
        if x >= t[-1]:
            return float(cumulative[-1] + rates[-1] * (x - t[-1]))
        i = int(np.searchsorted(t, x, side='right')) - 1
        rate_x = float(np.interp(x, t, rates))
        return float(cumulative[i] + 0.5 * (rates[i] + rate_x) * (x - t[i]))


def external_prior(prior: str, start_ns: int | None, end_ns: int,
                   odometry: OdometryBuffer | None = None,
                   imu: ImuBuffer | None = None) -> tuple[se2.Pose | None, float | None]:
    """Return ``(prior_step, prior_yaw)`` for ``OdometryPipeline.process``.

    ``start_ns`` is the stamp of the previous processed scan (``pipeline.last_stamp_ns``).
    Only the prior named by ``prior`` is looked up; the other stays None.
    """
    if start_ns is None or end_ns <= start_ns:
        return None, None
    if prior == 'odom' and odometry is not None:
        return odometry.motion_between(start_ns, end_ns), None
    if prior == 'imu' and imu is not None:
        return None, imu.yaw_change(start_ns, end_ns)
    return None, None


class PriorFeed:
    """Feeds the bag's wheel odometry / IMU samples into the prior buffers up to each scan.

    Offline all samples are known, so at a scan stamp every sample up to it and the
    first one after it are buffered - the buffers then interpolate instead of
    extrapolating, as they would once the next message had arrived live.
    """

    def __init__(self, prior: str, config: PriorConfig, odometry: Trajectory | None = None,
                 imu: ImuSamples | None = None) -> None:
        """Prepare the samples; ``prior`` picks which buffer is used."""
        self.prior = prior
        self.odometry = OdometryBuffer(config)
        self.imu = ImuBuffer(config)
        self.odometry_samples = odometry if prior == 'odom' else None
        self.imu_samples = imu if prior == 'imu' else None
        self._next = 0

    def stamps(self) -> np.ndarray:
        """Return the stamps of the active prior's samples (none without odom/imu prior)."""
        if self.odometry_samples is not None:
            return self.odometry_samples.stamps_ns
        if self.imu_samples is not None:
            return self.imu_samples.stamps_ns
        return np.zeros(0, dtype=np.int64)

    def advance(self, stamp_ns: int) -> range:
        """Buffer the samples up to ``stamp_ns`` and the first one after; return their indices."""
        stamps = self.stamps()
        end = min(int(np.searchsorted(stamps, stamp_ns, side='right')) + 1, len(stamps))
        new = range(self._next, max(end, self._next))
        for i in new:
            if self.odometry_samples is not None:
                self.odometry.add(int(stamps[i]), self.odometry_samples.poses[i])
            elif self.imu_samples is not None:
                yaw = float(self.imu_samples.yaw[i])
                self.imu.add(int(stamps[i]), yaw if np.isfinite(yaw) else None,
                             float(self.imu_samples.yaw_rate[i]))
        self._next = new.stop
        return new

    def prior_for(self, last_ns: int | None, stamp_ns: int) -> tuple[Any, float | None]:
        """Return ``(prior_step, prior_yaw)`` for the scan at ``stamp_ns``."""
        self.advance(stamp_ns)
        return external_prior(self.prior, last_ns, stamp_ns, self.odometry, self.imu)
