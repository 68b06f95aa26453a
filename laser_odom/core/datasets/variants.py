"""Datasets derived from a log: as a bag delivers it, with range noise, every k-th, faster.

A figure measured once on the in-memory log is an anecdote. What a user replays is
the log converted to a bag (``laser_odom_convert``): a ``sensor_msgs/LaserScan`` holds
its ranges and angles as float32, so the node never sees the float64 ranges the log
loader gives (:func:`as_received`). And a figure that moves when every range moves by
a millimetre (far below any scanner's noise) says more about one branch the run took
than about the method: :func:`with_range_noise` makes copies that no sensor could tell
apart, and the benchmark reports the spread over them.

Fast robots: taking every k-th scan of a full-rate log and stamping the scans
``period`` apart (:func:`restamped`) is what a robot k times faster records at
``1/period`` Hz. The constant-velocity prediction is then trusted (the scans are
close in time) while the steps are large: the case where a wrong prediction leads the
match astray (issue "Unseen places and fast robots").
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from laser_odom.core.scan.laser_scan import LaserScan
from laser_odom.core.trajectory import Dataset, Trajectory

RANGE_NOISE_M = 0.001
"""Standard deviation of the range noise of a perturbed copy [m]: 1 mm, far below any
scanner's own (SICK LMS about 1 cm)."""

FLOAT32_FIELDS = ('angle_min', 'angle_max', 'angle_increment', 'range_min', 'range_max',
                  'time_increment', 'scan_time')
"""The scalar fields of a ``sensor_msgs/LaserScan`` that the message holds as float32."""


def _float32(values: np.ndarray | None) -> np.ndarray | None:
    """Return ``values`` rounded to float32 and held as float64 (None stays None)."""
    if values is None:
        return None
    return np.asarray(values, dtype=np.float32).astype(float)


def scan_as_received(scan: LaserScan) -> LaserScan:
    """Return ``scan`` as a ``sensor_msgs/LaserScan`` carries it (float32 fields)."""
    scalars = {name: float(np.float32(getattr(scan, name))) for name in FLOAT32_FIELDS}
    return replace(scan, ranges=_float32(scan.ranges), intensities=_float32(scan.intensities),
                   **scalars)


def as_received(dataset: Dataset) -> Dataset:
    """Return the dataset as the node receives it from a bag or a live topic.

    Exactly what ``laser_odom_convert`` writes and the bag reader gives back: every
    float32 field of the message rounded to float32 (test_datasets checks the two
    agree bit for bit).
    """
    return replace(dataset, scans=[scan_as_received(scan) for scan in dataset.scans])


def with_range_noise(dataset: Dataset, seed: int, sigma: float = RANGE_NOISE_M,
                     name: str | None = None) -> Dataset:
    """Return a copy with zero-mean Gaussian noise of ``sigma`` [m] on every valid range.

    Valid: finite and within the scan's ``[range_min, range_max]`` (a no-return reading
    stays one). The noise is drawn from ``seed`` alone, so a copy is reproducible.
    """
    rng = np.random.default_rng(seed)
    scans = []
    for scan in dataset.scans:
        ranges = np.array(scan.ranges, dtype=float)
        valid = (np.isfinite(ranges) & (ranges >= scan.range_min)
                 & (ranges <= scan.range_max))
        noise = rng.normal(0.0, sigma, size=ranges.shape)
        ranges[valid] = np.clip(ranges[valid] + noise[valid], scan.range_min, scan.range_max)
        scans.append(replace(scan, ranges=ranges))
    return replace(dataset, scans=scans, name=name or dataset.name)


def _restamped_trajectory(trajectory: Trajectory, old_ns: np.ndarray,
                          new_ns: np.ndarray, exact: bool = False) -> Trajectory:
    """Return the trajectory's poses at ``old_ns`` stamped ``new_ns`` (where it covers).

    ``exact`` keeps only the poses stamped exactly at a scan (a reference given on
    keyframes stays on those keyframes); otherwise the pose is interpolated.
    """
    if exact:
        index = np.searchsorted(trajectory.stamps_ns, old_ns)
        index = np.minimum(index, len(trajectory) - 1)
        hit = trajectory.stamps_ns[index] == old_ns
        return Trajectory(new_ns[hit].astype(np.int64), trajectory.poses[index[hit]])
    stamps, poses = [], []
    for old, new in zip(old_ns.tolist(), new_ns.tolist()):
        pose = trajectory.interpolate(old)
        if pose is not None:
            stamps.append(new)
            poses.append(pose)
    return Trajectory(np.array(stamps, dtype=np.int64), np.array(poses).reshape(-1, 3))


def restamped(dataset: Dataset, period: float, name: str | None = None) -> Dataset:
    """Return the scans stamped ``period`` seconds apart from the first scan's stamp.

    The reference and the wheel odometry are taken at each scan's original stamp and
    carry its new stamp, so every scan keeps its pose: only the clock runs faster.
    A reference pose is carried only where it is stamped exactly at a kept scan (a
    keyframe reference stays on its keyframes; nothing is interpolated into it).
    """
    if not period > 0.0:
        raise ValueError(f'period must be positive, got {period:g}')
    if not dataset.scans:
        return replace(dataset, name=name or dataset.name)
    old_ns = np.array([scan.stamp_ns for scan in dataset.scans], dtype=np.int64)
    new_ns = old_ns[0] + np.round(np.arange(len(old_ns)) * period * 1e9).astype(np.int64)
    scans = [replace(scan, stamp_ns=int(stamp)) for scan, stamp in zip(dataset.scans, new_ns)]
    reference = (_restamped_trajectory(dataset.reference, old_ns, new_ns, exact=True)
                 if len(dataset.reference) else dataset.reference)
    odometry = (_restamped_trajectory(dataset.odometry, old_ns, new_ns)
                if len(dataset.odometry) else dataset.odometry)
    return Dataset(name or dataset.name, scans, odometry, reference)


@dataclass(frozen=True)
class DerivedSpec:
    """A dataset derived from a known log: every ``every``-th scan, re-stamped or not."""

    base: str
    every: int = 1
    period: float | None = None
    """Seconds between the derived scans' stamps; None keeps the recorded stamps."""

    def derive(self, base: Dataset, name: str) -> Dataset:
        """Return the derived dataset of ``base`` (the loaded :attr:`base` log)."""
        dataset = base.every(self.every, name)
        return dataset if self.period is None else restamped(dataset, self.period, name)
