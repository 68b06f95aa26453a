"""Drive the odometry pipeline over a recorded sequence of scans (replay, benchmark, tests).

This is the offline twin of the node's scan callback: the same pipeline object, the
same priors, one estimate per processed scan.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Callable, Iterable

import numpy as np

from laser_odom.core.motion.priors import PriorFeed
from laser_odom.core.pipeline.estimate import OdometryEstimate
from laser_odom.core.pipeline.odometry import OdometryPipeline
from laser_odom.core.scan.laser_scan import LaserScan
from laser_odom.core.trajectory import Trajectory

ProgressCallback = Callable[[int], None]
EstimateCallback = Callable[[OdometryEstimate], None]


@dataclass
class RunResult:
    """Estimated trajectory (one pose per processed scan) and run statistics."""

    trajectory: Trajectory
    pose_covariances: np.ndarray
    processing_times: np.ndarray
    counters: Counter = field(default_factory=Counter)
    step_covariances: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    """Per estimate, the covariance of its match (zero for an ``initialized`` scan): what
    :mod:`laser_odom.core.evaluation.consistency` propagates over windows of steps. The stamps are
    ``trajectory.stamps_ns``."""
    statuses: list[str] = field(default_factory=list)
    """Per estimate, its status (``initialized``, ``matched``, ``degenerate``, ``rejected``)."""

    @property
    def processed(self) -> int:
        """Number of scans that produced an estimate."""
        return len(self.trajectory)


def run_pipeline(pipeline: OdometryPipeline, scans: Iterable[LaserScan],
                 priors: PriorFeed | None = None,
                 progress: ProgressCallback | None = None,
                 on_estimate: EstimateCallback | None = None) -> RunResult:
    """Feed ``scans`` through ``pipeline`` in order and collect the estimates.

    ``priors`` supplies each match's wheel-odometry step or IMU yaw change (used when
    the pipeline's ``prior`` asks for it), exactly as the node's buffers do live.
    ``progress`` is called with the number of scans consumed, ``on_estimate`` with
    every estimate as it is made (so a caller keeps what was done if reading fails).
    """
    stamps: list[int] = []
    poses: list[np.ndarray] = []
    covariances: list[np.ndarray] = []
    times: list[float] = []
    step_covariances: list[np.ndarray] = []
    statuses: list[str] = []
    for count, scan in enumerate(scans, start=1):
        step, yaw = (None, None) if priors is None else priors.prior_for(
            pipeline.last_stamp_ns, scan.stamp_ns)
        estimate = pipeline.process(scan, step, yaw)
        if estimate is not None:
            estimate.processing_time += pipeline.prepare_next()
            stamps.append(estimate.stamp_ns)
            poses.append(estimate.pose)
            covariances.append(estimate.pose_covariance)
            times.append(estimate.processing_time)
            step_covariances.append(np.zeros((3, 3)) if estimate.step_covariance is None
                                    else estimate.step_covariance)
            statuses.append(estimate.status)
            if on_estimate is not None:
                on_estimate(estimate)
        if progress is not None:
            progress(count)
    return RunResult(
        trajectory=Trajectory(np.array(stamps, dtype=np.int64), np.array(poses).reshape(-1, 3)),
        pose_covariances=np.array(covariances).reshape(-1, 3, 3),
        processing_times=np.array(times), counters=Counter(pipeline.counters),
        step_covariances=np.array(step_covariances).reshape(-1, 3, 3), statuses=statuses)
