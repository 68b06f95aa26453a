"""The scan-to-scan odometry pipeline that the node and the replay harness both drive.

Per scan: preprocess (validate, convert to base-frame points), predict the motion
(constant velocity or an external prior), register against the reference scan, judge
the match (acceptance, degeneracy), then integrate pose, twist and covariance.
"""

from __future__ import annotations

import time
from collections import Counter, deque
from dataclasses import dataclass

import numpy as np

from laser_odom.core import se2
from laser_odom.core.config import PipelineConfig
from laser_odom.core.matchers import matcher_class, MatchResult, ScanMatcher
from laser_odom.core.acceptance import judge_match
from laser_odom.core.motion import MotionModel
from laser_odom.core.scan import LaserScan, ScanPoints
from laser_odom.core.validation import ScanValidator

TIMING_WINDOW = 1000
"""Number of recent per-scan processing times kept for statistics."""


@dataclass
class OdometryEstimate:
    """Odometry after one scan: pose of the base in the odom frame, and its twist.

    ``twist`` is ``[vx, vy, wz]`` in the base frame (REP-105); covariances are 3x3 in
    ``[x, y, yaw]``. ``status`` is ``initialized``, ``matched``, ``degenerate`` or
    ``rejected``; ``processing_time`` is seconds spent on this scan.
    """

    stamp_ns: int
    pose: np.ndarray
    pose_covariance: np.ndarray
    twist: np.ndarray
    twist_covariance: np.ndarray
    status: str
    match: MatchResult | None = None
    processing_time: float = 0.0


class OdometryPipeline:
    """Scan-to-scan (or scan-to-keyframe) laser odometry, independent of ROS."""

    def __init__(self, config: PipelineConfig | None = None,
                 matcher: ScanMatcher | None = None) -> None:
        """Create the pipeline; the matcher defaults to ``config.matcher``."""
        self.config = config if config is not None else PipelineConfig()
        if matcher is None:
            matcher = matcher_class(self.config.matcher)(self.config.resolved_matcher_config())
        self.matcher = matcher
        self.validator = ScanValidator(self.config.scan, self.config.mounting)
        self.motion = MotionModel(self.config.motion)
        self.counters: Counter[str] = Counter()
        self.processing_times: deque[float] = deque(maxlen=TIMING_WINDOW)
        self.reset()

    def reset(self, pose: se2.Pose | None = None,
              covariance: np.ndarray | None = None) -> None:
        """Restart integration from ``pose`` (default: the origin), forgetting the reference."""
        self.pose = se2.pose() if pose is None else np.array(pose, dtype=float)
        self.pose_covariance = np.zeros((3, 3)) if covariance is None else np.array(covariance)
        self.keyframe: ScanPoints | None = None
        self.keyframe_pose = self.pose.copy()
        self.keyframe_covariance = self.pose_covariance.copy()
        self.last_stamp_ns: int | None = None
        self.motion.reset()

    def set_matcher(self, matcher: ScanMatcher) -> None:
        """Switch the matcher; the pose and the reference scan are kept."""
        self.matcher = matcher
        self.config.matcher = matcher.name
        self.config.matcher_config = matcher.config

    def process(self, scan: LaserScan, prior_step: se2.Pose | None = None,
                prior_yaw: float | None = None) -> OdometryEstimate | None:
        """Process one scan; return the new odometry, or None if the scan was skipped.

        ``prior_step`` (wheel odometry motion since the previous processed scan) and
        ``prior_yaw`` (IMU yaw change) are used when the ``prior`` parameter asks for
        them; when missing, the constant-velocity prediction stands in.
        """
        started = time.perf_counter()
        self.counters['scans_in'] += 1
        current, reason = self.validator.check(scan)
        if current is None:
            self.counters[reason] += 1
            return None
        dt = self._elapsed(scan.stamp_ns)
        if dt is None:
            return None
        if self.keyframe is None:
            estimate = self._initialise(current, scan.stamp_ns)
        else:
            guess_step = self.motion.predict(dt, prior_step, prior_yaw, self.counters)
            estimate = self._register(current, guess_step, dt, scan.stamp_ns)
        estimate.processing_time = time.perf_counter() - started
        self.processing_times.append(estimate.processing_time)
        self.counters['processed'] += 1
        self.counters[estimate.status] += 1
        return estimate

    def _elapsed(self, stamp_ns: int) -> float | None:
        """Return seconds since the last processed scan; handle repeats and time jumps."""
        last = self.last_stamp_ns
        if last is not None and stamp_ns == last:
            self.counters['duplicate_stamp'] += 1
            return None
        if last is not None and stamp_ns < last:
            self.counters['time_jump_back'] += 1
            self.reset()
            last = None
        self.last_stamp_ns = stamp_ns
        return 0.0 if last is None else (stamp_ns - last) * 1e-9

    def _initialise(self, current: ScanPoints, stamp_ns: int) -> OdometryEstimate:
        """Take the first scan (or the first after a reset) as the reference."""
        self._set_keyframe(current)
        return OdometryEstimate(stamp_ns, self.pose.copy(), self.pose_covariance.copy(),
                                np.zeros(3), np.eye(3) * 1e-6, 'initialized')

    def _register(self, current: ScanPoints, guess_step: se2.Pose, dt: float,
                  stamp_ns: int) -> OdometryEstimate:
        """Match against the keyframe, judge the match and integrate the step."""
        guess = se2.relative(self.keyframe_pose, se2.compose(self.pose, guess_step))
        match = self.matcher.match(self.keyframe, current, guess)
        verdict = judge_match(match, guess, self.config.acceptance)
        new_pose = se2.compose(self.keyframe_pose, verdict.pose)
        ja, jb = se2.compose_jacobians(self.keyframe_pose, verdict.pose)
        new_covariance = (ja @ self.keyframe_covariance @ ja.T
                          + jb @ verdict.covariance @ jb.T)
        step = se2.relative(self.pose, new_pose)
        step_covariance = verdict.covariance
        self.pose, self.pose_covariance = new_pose, 0.5 * (new_covariance + new_covariance.T)
        self.motion.update(step, dt)
        if verdict.status != 'rejected' and self._keyframe_expired(verdict.pose):
            self._set_keyframe(current)
        twist = step / dt if dt > 0 else np.zeros(3)
        twist_cov = step_covariance / (dt * dt) if dt > 0 else step_covariance * 1e6
        return OdometryEstimate(stamp_ns, new_pose, self.pose_covariance.copy(), twist,
                                twist_cov, verdict.status, match)

    def _keyframe_expired(self, keyframe_to_current: se2.Pose) -> bool:
        """Tell whether the current scan becomes the new reference."""
        kf = self.config.keyframes
        if kf.keyframe_distance <= 0.0 and kf.keyframe_angle <= 0.0:
            return True
        moved = float(np.hypot(keyframe_to_current[0], keyframe_to_current[1]))
        turned = abs(float(keyframe_to_current[2]))
        return ((kf.keyframe_distance > 0.0 and moved >= kf.keyframe_distance)
                or (kf.keyframe_angle > 0.0 and turned >= kf.keyframe_angle))

    def _set_keyframe(self, current: ScanPoints) -> None:
        """Make ``current`` the reference of the next matches."""
        self.keyframe = current
        self.keyframe_pose = self.pose.copy()
        self.keyframe_covariance = self.pose_covariance.copy()
