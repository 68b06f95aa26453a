"""The odometry pipeline that the node and the replay harness both drive.

Per scan: preprocess (validate, convert to base-frame points), predict the motion
(constant velocity or an external prior) and decide whether that prediction can be
trusted, register against the reference (the previous scan or keyframe, or the local
map with ``reference: local_map``: the matcher from the prediction, the
global search when the prediction or the match fails), judge the match (acceptance,
ambiguity, degeneracy), then integrate pose, twist and covariance.
"""

from __future__ import annotations

from collections import Counter, deque
import time

import numpy as np

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import PipelineConfig
from laser_odom.core.events import EventLog
from laser_odom.core.matchers import matcher_class, MatchResult, ScanMatcher
from laser_odom.core.motion.model import fused_with_prediction, MotionModel
from laser_odom.core.pipeline.announce import say_evidence, say_why
from laser_odom.core.pipeline.estimate import OdometryEstimate, UNKNOWN_TWIST_VARIANCE
from laser_odom.core.pipeline.reconfigure import LiveReconfiguration
from laser_odom.core.pipeline.reference import ReferenceKeeping
from laser_odom.core.preprocess.deskew import (
    deskew_change, deskewed, MidSweepTwist, sweeps_after_stamp, SweepTwist, twist_of_step)
from laser_odom.core.preprocess.validation import REJECTIONS, ScanValidator
from laser_odom.core.registration.acceptance import (
    judge_again, judge_match, measured_covariance, published_covariance)
from laser_odom.core.registration.map_registrar import JudgedMatch, MapRegistrar
from laser_odom.core.registration.registrar import Registrar
from laser_odom.core.scan.laser_scan import LaserScan, ScanPoints
from laser_odom.core.uncertainty.pose_uncertainty import PoseUncertainty, step_error

TIMING_WINDOW = 1000
"""Number of recent per-scan processing times kept for statistics."""

DESKEW_TOLERANCE = 0.02
"""Match again when the measured twist would move the de-skewed points more than this
[m] (a bound over the sweep; below it the twist differs by less than matching noise)."""


class OdometryPipeline(LiveReconfiguration, ReferenceKeeping):
    """Scan-to-scan (or scan-to-keyframe, or scan-to-map) laser odometry, independent of ROS.

    New settings take effect from the next scan on (:meth:`configure`, in
    :class:`.reconfigure.LiveReconfiguration`).
    """

    def __init__(self, config: PipelineConfig | None = None,
                 matcher: ScanMatcher | None = None, events: EventLog | None = None) -> None:
        """Create the pipeline; the matcher defaults to ``config.matcher``.

        ``events`` receives counted, throttled warnings about bad input and failed
        matches (default: the ``laser_odom`` Python logger).
        """
        self.config = config if config is not None else PipelineConfig()
        if matcher is None:
            matcher = matcher_class(self.config.matcher)(self.config.resolved_matcher_config())
        self.matcher = matcher
        self.events = events if events is not None else EventLog()
        self.counters: Counter[str] = self.events.counters
        self.validator = ScanValidator(self.config.scan, self.config.mounting, self.events)
        self.motion = MotionModel(self.config.motion)
        self.registrar = Registrar(self.events)
        self.processing_times: deque[float] = deque(maxlen=TIMING_WINDOW)
        self.map_registrar = self._map_registrar(self.config)
        self.reset()

    def _map_registrar(self, config: PipelineConfig) -> MapRegistrar | None:
        """Return a new local map when scans are matched against one, else None."""
        if config.local_map.reference != 'local_map':
            return None
        return MapRegistrar(config, self.events)

    def map_cells(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Return a copy of the local map's cells: means (N, 2, odom frame), weights.

        For display (the node's ``~/local_map``); None with ``reference: scan``.
        """
        if self.map_registrar is None:
            return None
        return self.map_registrar.map.map.cell_means()

    def reset(self, pose: se2.Pose | None = None,
              covariance: np.ndarray | None = None) -> None:
        """Restart integration from ``pose`` (default: the origin), forgetting the reference."""
        self.pose = se2.pose() if pose is None else np.array(pose, dtype=float)
        self.pose_covariance = np.zeros((3, 3)) if covariance is None else np.array(covariance)
        self.keyframe: ScanPoints | None = None
        self.keyframe_deskewed = False
        self.keyframe_prepared = False
        self.keyframe_pose = self.pose.copy()
        self.uncertainty = PoseUncertainty.at(self.pose_covariance)
        self.keyframe_uncertainty = self.uncertainty
        self.scans_after_keyframe = 0
        self.last_stamp_ns: int | None = None
        self.sweep_clock_ns = 0
        self.map_seed: ScanPoints | None = None
        self.untrusted = 'reset'
        self.motion.reset()
        self.sweep_twist = SweepTwist()
        self.mid_sweep_twist = MidSweepTwist()
        if self.map_registrar is not None:
            self.map_registrar.reset()

    def process(self, scan: LaserScan, prior_step: se2.Pose | None = None,
                prior_yaw: float | None = None) -> OdometryEstimate | None:
        """Process one scan; return the new odometry, or None if the scan was skipped.

        ``prior_step`` (wheel odometry motion since the previous processed scan) and
        ``prior_yaw`` (IMU yaw change) are used when the ``prior`` parameter asks for
        them; when missing, the constant-velocity prediction stands in.
        """
        started = time.perf_counter()
        self.counters['scans_in'] += 1
        scan = self.validator.thin(scan)
        current, reason = self.validator.check(scan)
        if current is None:
            self.events.warn(reason, f'scan at t={scan.stamp_ns * 1e-9:.3f} skipped: '
                             f'{REJECTIONS[reason]}')
            return None
        dt = self._elapsed(scan.stamp_ns)
        if dt is None:
            return None
        if self.map_registrar is not None:
            self.map_registrar.observe_scan(scan)
        if self.keyframe is None:
            estimate = self._initialise(current, scan.stamp_ns)
        else:
            untrusted = self._distrust(dt, scan.stamp_ns, prior_step)
            guess_step = self.motion.predict(dt, prior_step, prior_yaw, self.counters)
            carried = self.motion.carried_covariance(dt)
            self.registrar.expect(carried)
            if self.map_registrar is not None:
                self.map_registrar.expect(carried)
            estimate = self._register(current, guess_step, dt, scan.stamp_ns, untrusted)
        estimate.processing_time = time.perf_counter() - started
        self.processing_times.append(estimate.processing_time)
        self.counters['processed'] += 1
        self.counters[estimate.status] += 1
        return estimate

    def _elapsed(self, stamp_ns: int) -> float | None:
        """Return seconds since the last processed scan; handle repeats and time jumps."""
        last = self.last_stamp_ns
        if last is not None and stamp_ns == last:
            self.events.warn('duplicate_stamp', f'scan at t={stamp_ns * 1e-9:.3f} skipped: '
                             'same stamp as the previous scan')
            return None
        if last is not None and stamp_ns < last:
            self.events.warn('time_jump_back', f'scan stamp t={stamp_ns * 1e-9:.3f} is '
                             f'earlier than the previous t={last * 1e-9:.3f} (bag loop or '
                             'restarted clock): odometry reset to the origin')
            self.reset()
            last = None
        self.last_stamp_ns = stamp_ns
        return 0.0 if last is None else (stamp_ns - last) * 1e-9

    def _distrust(self, dt: float, stamp_ns: int, prior_step: se2.Pose | None = None) -> str:
        """Return why this match's prediction cannot be trusted ('' when it can)."""
        motion = self.config.motion
        if motion.prior == 'none':
            return 'no_prior'
        if self.motion.gap_exceeded(dt, prior_step):
            self.events.warn('scan_gap', f'{dt:.2f} s between the scans before '
                             f't={stamp_ns * 1e-9:.3f}, longer than max_scan_gap '
                             f'({motion.max_scan_gap:g} s): the motion prior is dropped')
            return 'gap'
        return self.untrusted

    def _initialise(self, current: ScanPoints, stamp_ns: int) -> OdometryEstimate:
        """Take the first scan (or the first after a reset) as the reference.

        Its sweep motion is not known yet: it is de-skewed once the first match
        measures the motion (:meth:`_deskew_again`). Nor is its twist: it is zero with
        :data:`UNKNOWN_TWIST_VARIANCE`, so that a filter takes it for no measurement.
        """
        self._set_keyframe(current, motion_known=False)
        if self.map_registrar is not None:
            self.map_registrar.restart(current, self.pose)
            self.map_seed = current if current.times is not None else None
        return OdometryEstimate(stamp_ns, self.pose.copy(), self.pose_covariance.copy(),
                                np.zeros(3), np.eye(3) * UNKNOWN_TWIST_VARIANCE,
                                'initialized', scan_points=current.points)

    def _register(self, current: ScanPoints, guess_step: se2.Pose, dt: float,
                  stamp_ns: int, untrusted: str) -> OdometryEstimate:
        """Match against the keyframe, judge the match and integrate the step."""
        if self.map_registrar is not None:
            self._use_map_view()
        guess = se2.relative(self.keyframe_pose, se2.compose(self.pose, guess_step))
        sweep_dt = self._sweep_interval(dt, current)
        self.sweep_clock_ns += round(sweep_dt * 1e9)
        sweep_twist = twist_of_step(guess_step, sweep_dt)
        if (self.map_registrar is not None and not untrusted
                and self.motion.guess_source == 'constant_velocity'):
            sweep_twist = self.mid_sweep_twist.predicted(sweep_twist)
        current = deskewed(current, sweep_twist)
        if not self.keyframe_deskewed and deskew_change(self.keyframe, sweep_twist) > 0.0:
            self.keyframe = deskewed(self.keyframe, sweep_twist)  # its sweep: this step
        if self.map_registrar is None:
            registration = self.registrar.register(self.matcher, self.keyframe, current,
                                                   guess, self.config, untrusted)
            judged = JudgedMatch(self.keyframe, self.registrar, registration, judge_match(
                registration, guess, self.config, current.length_scale), False)
        else:
            judged = self.map_registrar.register(self.matcher, self.registrar, self.keyframe,
                                                 current, guess, self.config, untrusted)
        say_why(self.events, judged.registration, judged.verdict, guess, stamp_ns,
                self.config)
        say_evidence(self.events, judged.registration, judged.verdict.status,
                     f't={stamp_ns * 1e-9:.3f}')
        if current.times is not None and judged.verdict.status != 'rejected':
            current, judged = self._deskew_again(current, sweep_dt, judged)
        if self.map_registrar is not None:
            judged = self.map_registrar.refine_on_surfaces(self.matcher, current, judged,
                                                           self.keyframe_pose)
        registration, verdict = judged.registration, judged.verdict
        new_pose = se2.compose(self.keyframe_pose, verdict.pose)
        step_covariance, model = step_error(
            verdict.status, published_covariance(verdict, registration.match),
            self.matcher.config, judged.from_map, judged.doubt)
        self.scans_after_keyframe += 1
        self.uncertainty = self.keyframe_uncertainty.propagate(
            self.keyframe_pose, verdict.pose, step_covariance, model,
            self.scans_after_keyframe)
        step = se2.relative(self.pose, new_pose)
        previous_pose = self.pose
        self.pose, self.pose_covariance = new_pose, self.uncertainty.pose_covariance
        if verdict.status == 'rejected':
            # The prediction may be what was wrong: keeping its velocity would make every
            # later (correct) match a large correction, and the odometry would run away
            # on the prediction. The next match starts from rest, untrusted.
            self.motion.reset()
            self.mid_sweep_twist.forget()
            self.untrusted = 'rejected'
        elif registration.match.extra.get('poor_fit'):
            # Even the widened search found no pose that fits well: the step taken is a
            # best guess, announced with a covariance over the window, and a velocity
            # from it would send the next prediction astray (fr079 every 10th scan at
            # 10 Hz: a 5 m guess, then a rejection published as the guess). The next
            # match starts from rest, searched.
            self.motion.reset()
            judged.registrar.accepted(registration.match)
            self.untrusted = 'poor_fit'
        elif registration.alternatives:
            # Poses that fit alike (a featureless corridor): the step taken is one of
            # them, not a measured motion, and a velocity from it would carry the pick on
            # for good. The velocity stays that of the prediction (none if untrusted).
            if untrusted:
                self.motion.reset()
            judged.registrar.accepted(registration.match, verdict.status)
            self.untrusted = ''
        else:
            if verdict.status == 'matched':
                self.motion.update(step, dt)
            else:
                self._update_velocity(guess_step, step, step_covariance, registration.match,
                                      previous_pose, current.length_scale, dt, untrusted)
            judged.registrar.accepted(registration.match, verdict.status)
            self.untrusted = ''
        if self.map_registrar is not None:
            self.keyframe_prepared = False  # the next match sees the map from the new pose
            self.map_registrar.update(current, self.pose, judged, self.registrar, stamp_ns)
        elif verdict.status == 'rejected' or self._keyframe_expired(verdict.pose):
            # After a rejection the current scan becomes the reference at the predicted
            # pose: a bad prediction then costs one step, instead of misleading every
            # following match against the old reference.
            self._set_keyframe(current, motion_known=verdict.status != 'rejected')
        rate_dt = self.motion.effective_dt(dt)
        twist = step / rate_dt if rate_dt > 0 else np.zeros(3)
        twist_cov = (step_covariance / (rate_dt * rate_dt) if rate_dt > 0
                     else step_covariance * 1e6)
        return OdometryEstimate(stamp_ns, new_pose, self.pose_covariance.copy(), twist,
                                twist_cov, verdict.status, registration.match,
                                scan_points=current.points, step_covariance=step_covariance)

    def _update_velocity(self, guess_step: se2.Pose, step: se2.Pose,
                         step_covariance: np.ndarray, match: MatchResult,
                         previous_pose: se2.Pose, length_scale: float, dt: float,
                         untrusted: str) -> None:
        """Record a step that is not well constrained in the velocity.

        With ``velocity_update: replace`` (the default) the step becomes the velocity,
        its covariance carried on as the velocity's own error
        (:meth:`.MotionModel.carried_covariance`). Taken outright, a step the scan
        hardly measured (a searched pose among the pillars of a hall, announced with a
        metre of deviation) sends the next predictions astray: 24 failed steps on one
        noise copy of the simulated fast hall (plicp, scan to scan). With ``weighed``,
        from a trusted constant-velocity prediction with a measured error, the velocity
        is the prediction corrected by what the scans alone measured
        (:func:`.model.fused_with_prediction`, :func:`.acceptance.measured_covariance`),
        and the result's error is carried on: 4 failed steps there. Where the motion
        changes abruptly between scans a prediction and a weak step are alike likely
        wrong, and their average is neither: intel's keyframes 0.1 s apart, nicp,
        failed 6 steps instead of 4 scan to scan, 9 instead of 4 against the map.
        Measured again over 3 noise copies (2026-12-07, failed steps summed): intel-kf-fast
        nicp 15 -> 21 scan to scan, 15 -> 24 against the map. Weighing only a step within
        a 99.9 % gate of the prediction (squared Mahalanobis distance of the innovation
        16.27; beyond it the step replaced the velocity) gave the simulated hall (3 seeds,
        slow and fast) plicp scan to scan 59 -> 39 failed steps, but intel-kf-fast nicp
        still 21 scan to scan and plicp 24 -> 28 against the map: neither is the default.
        """
        prior = None
        if (self.config.motion.velocity_update == 'weighed' and not untrusted
                and self.motion.guess_source in ('constant_velocity', 'imu')):
            prior = self.registrar.history.covariance(self.motion.effective_dt(dt))
        if prior is None:
            self.motion.update(step, dt, step_covariance)
            return
        between = se2.relative(previous_pose, self.keyframe_pose)
        _, axes = se2.compose_jacobians(between, match.pose)  # the reference's -> the step's
        covariance = axes @ measured_covariance(match, self.config.acceptance,
                                                length_scale) @ axes.T
        velocity_step, velocity_covariance = fused_with_prediction(
            guess_step, prior + self.motion.carried_covariance(dt),
            se2.compose(between, match.pose), covariance)
        self.motion.update(velocity_step, dt, velocity_covariance)

    def _sweep_interval(self, dt: float, current: ScanPoints) -> float:
        """Return the interval [s] the step's twist is measured over, for de-skewing.

        The stamps' interval as the motion model reads it (:meth:`.MotionModel.effective_dt`:
        the mean interval of logger-stamped, bursty stamps), and at least the scan's own
        sweep: a scanner finishes one sweep before it starts the next. Bursty stamps 1 ms
        apart taken as the interval made every de-skew twist 200 times too large (the
        simulated office with a 5 Hz 360 deg lidar, odd scans stamped 1 ms after their
        predecessor: plicp and nicp 35 and 31 failed steps, 12 silent each, against 0).
        """
        interval = self.motion.effective_dt(dt)
        if current.times is not None and len(current.times):
            interval = max(interval, float(np.ptp(current.times)))
        return interval

    def _deskew_again(self, current: ScanPoints, sweep_dt: float, judged: JudgedMatch
                      ) -> tuple[ScanPoints, JudgedMatch]:
        """De-skew with the twist the match measured, and match again if it matters.

        The prediction's twist was a guess (zero with ``prior: none``); the match tells
        the motion over the step from the reference's stamp to the current one. That
        interval holds the reference's sweep when scans are stamped at their first beam,
        and the current sweep when stamped at the last; the other sweep is predicted
        with the same twist (constant velocity). When the measured twist would move the
        current points - or those of a reference not yet de-skewed with a measured twist
        - by more than :data:`DESKEW_TOLERANCE`, they are de-skewed again and matched
        again from the first match, which is kept if the second is rejected. The
        reference takes the measured twist; the current scan the one over its own sweep:
        extrapolated scan to scan (:class:`.deskew.SweepTwist`), from mid-sweep poses
        against the map (:class:`.deskew.MidSweepTwist`), which then decides whether it
        matters.

        The verdict stays degenerate when the first was (:func:`.acceptance.judge_again`),
        but what is decided after it - the velocity, the step history, whether the scan
        joins the local map - reads the second match's own evidence, not the first's
        alternatives and weak flags. Carrying those over was measured (3 seeds of the
        campus and hall worlds, 3 noise copies, both references): failed steps against
        the map rose from 1 to 22 (imls) and 9 to 17 (plicp), scan to scan plicp 30 to
        37; keeping the velocity after a weakly constrained step too gave plicp 64.
        """
        verdict, reference = judged.verdict, judged.reference
        matched_pose = se2.compose(self.keyframe_pose, verdict.pose)
        measured = twist_of_step(se2.relative(self.pose, matched_pose), sweep_dt)
        stale_reference = not self.keyframe_deskewed
        self.keyframe_deskewed = True
        reference_shift = deskew_change(self.keyframe, measured) if stale_reference else 0.0
        if self.map_registrar is None:  # the map is not de-skewed with it: SweepTwist
            changed = max(reference_shift,
                          deskew_change(current, measured)) > DESKEW_TOLERANCE
            current_twist = self.sweep_twist.over_sweep(
                measured, self.sweep_clock_ns, sweep_dt, sweeps_after_stamp(current), changed)
        else:  # poses anchored on the map: MidSweepTwist
            current_twist = self.mid_sweep_twist.blended(measured, matched_pose, current,
                                                         self.sweep_clock_ns)
            changed = max(reference_shift,
                          deskew_change(current, current_twist)) > DESKEW_TOLERANCE
            straightened = self._straighten_map_seed(reference, measured)
            if straightened is not None:  # matched against the bent map: no pose to keep
                self.mid_sweep_twist.forget()
                reference, changed = straightened, True
        if not changed:
            return current, judged
        if reference_shift > DESKEW_TOLERANCE:
            self.keyframe = reference = deskewed(self.keyframe, measured)
        again_points = deskewed(current, current_twist)
        again = judged.registrar.register(self.matcher, reference, again_points,
                                          verdict.pose, self.config, '', verify=False)
        second = judge_again(verdict, again, self.config, again_points.length_scale)
        if second.status == 'rejected':
            return current, judged
        return again_points, judged._replace(reference=reference, registration=again,
                                             verdict=second)
