"""Time-stamped planar trajectories and datasets: the exchange format of the tools.

Importers, the simulator, bag readers and writers, the benchmark and the metrics all
speak these two types, so each data format needs exactly one loader.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from laser_odom.core import se2
from laser_odom.core.scan.laser_scan import LaserScan


@dataclass
class Trajectory:
    """Poses ``[x, y, theta]`` (N, 3) at increasing integer-nanosecond stamps (N,)."""

    stamps_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    def __post_init__(self) -> None:
        """Coerce to arrays of the right dtype and shape."""
        self.stamps_ns = np.asarray(self.stamps_ns, dtype=np.int64).reshape(-1)
        self.poses = np.asarray(self.poses, dtype=float).reshape(-1, 3)
        if self.stamps_ns.shape[0] != self.poses.shape[0]:
            raise ValueError('a trajectory needs one stamp per pose')

    def __len__(self) -> int:
        """Return the number of poses."""
        return int(self.stamps_ns.shape[0])

    @property
    def stamps(self) -> np.ndarray:
        """Stamps in seconds."""
        return self.stamps_ns * 1e-9

    def interpolate(self, stamp_ns: int) -> se2.Pose | None:
        """Return the pose at ``stamp_ns`` (linear in x, y and unwrapped theta).

        None when the stamp is outside the trajectory's time span.
        """
        n = len(self)
        if n == 0 or stamp_ns < self.stamps_ns[0] or stamp_ns > self.stamps_ns[-1]:
            return None
        i = int(np.searchsorted(self.stamps_ns, stamp_ns, side='right')) - 1
        if i >= n - 1 or self.stamps_ns[i] == stamp_ns:
            return self.poses[min(i, n - 1)].copy()
        t0, t1 = self.stamps_ns[i], self.stamps_ns[i + 1]
        alpha = (stamp_ns - t0) / (t1 - t0)
        a, b = self.poses[i], self.poses[i + 1]
        dtheta = se2.wrap_angle(b[2] - a[2])
        return np.array([a[0] + alpha * (b[0] - a[0]), a[1] + alpha * (b[1] - a[1]),
                         se2.wrap_angle(a[2] + alpha * dtheta)])

    def motion_between(self, start_ns: int, end_ns: int) -> se2.Pose | None:
        """Return the motion (in the frame of the start pose) between two stamps."""
        start, end = self.interpolate(start_ns), self.interpolate(end_ns)
        if start is None or end is None:
            return None
        return se2.relative(start, end)


@dataclass
class ImuSamples:
    """IMU heading samples: stamps [ns], yaw [rad] (NaN when not provided), yaw rate [rad/s]."""

    stamps_ns: np.ndarray
    yaw: np.ndarray
    yaw_rate: np.ndarray

    def __len__(self) -> int:
        """Return the number of samples."""
        return int(self.stamps_ns.shape[0])


@dataclass
class Dataset:
    """Scans with optional raw wheel odometry and an optional reference trajectory.

    ``reference`` is ground truth for simulated data and the corrected (SLAM) poses
    for real logs; it may cover only keyframes.
    """

    name: str
    scans: list[LaserScan]
    odometry: Trajectory = field(default_factory=Trajectory)
    reference: Trajectory = field(default_factory=Trajectory)

    def every(self, k: int, name: str | None = None) -> 'Dataset':
        """Return every ``k``-th scan (from the first), with the same odometry and reference.

        Large motion between scans from a full-rate log: as if the sensor were k times
        slower, or the odometry fell behind and skipped scans.
        """
        if k < 1:
            raise ValueError('k must be at least 1')
        return Dataset(name or f'{self.name}/{k}', self.scans[::k], self.odometry,
                       self.reference)


@dataclass
class RecordedBag:
    """One recorded bag in memory, as the tools use it: scans, priors and reference.

    ``name`` is the bag's path; ``odometry`` is the wheel odometry (the ``odom`` prior
    and the tuner's ``--odom-agreement``); ``reference_source`` names the reference (a
    TUM file or the bag's ``/ground_truth`` topic) in messages.
    """

    name: str
    scans: list[LaserScan]
    odometry: Trajectory | None = None
    imu: ImuSamples | None = None
    reference: Trajectory | None = None
    reference_source: str | None = None
