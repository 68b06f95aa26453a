"""The reference of the next match: a keyframe scan, or the local map seen from the pose.

Scan to scan, the current scan becomes the reference when the robot has moved or
turned far enough from the last keyframe (``keyframe_distance``, ``keyframe_angle``;
both 0: every scan), or after a rejected match. Against the local map, the reference
is the map's view from the previous pose, rendered anew after every scan. A mixin of
:class:`.odometry.OdometryPipeline`: its methods use the pipeline's pose, reference
state, matcher and local map.
"""

from __future__ import annotations

import time

import numpy as np

from laser_odom.core import se2
from laser_odom.core.preprocess.deskew import deskew_change, deskewed, sweeps_after_stamp
from laser_odom.core.scan.laser_scan import ScanPoints

MAP_SEED_BEND_CELLS = 4
"""The local map's first scan is de-skewed again with the first measured twist when that
moves its points by more than this many map cells
(:meth:`ReferenceKeeping._straighten_map_seed`)."""


class ReferenceKeeping:
    """Which scan (or map view) the next match is made against, and its preparation."""

    def prepare_next(self) -> float:
        """Do a new keyframe's reference-only work now; return the seconds it took.

        Call after the result of :meth:`process` is out (published, written): matching
        against a new keyframe needs structures that only its role as the reference
        uses (:meth:`.ScanMatcher.prepare_reference`), and building them here keeps
        them off the receipt-to-publish path. The result never depends on this call;
        without it the next match builds the same on demand. The time counts in the
        scan's processing time. A keyframe that the next match will de-skew again (its
        sweep follows its stamp) is replaced by then, so it is not prepared. Against a
        local map, the scan waiting to join it joins now, and the view from the new pose
        is rendered and prepared.
        """
        keyframe = self.keyframe
        if (keyframe is None or self.keyframe_prepared
                or (not self.keyframe_deskewed and keyframe.times is not None)):
            return 0.0
        started = time.perf_counter()
        if self.map_registrar is not None:
            keyframe = self._use_map_view()
        self.matcher.prepare_reference(keyframe)
        self.keyframe_prepared = True
        elapsed = time.perf_counter() - started
        if self.processing_times:
            self.processing_times[-1] += elapsed
        return elapsed

    def _use_map_view(self) -> ScanPoints:
        """Make the local map seen from the current pose the reference of the next match.

        Every match then starts from the previous pose, as scan to scan does: the
        estimate is the step, and its covariance compounds like a step's.
        """
        view = self.map_registrar.view(self.pose, self.last_stamp_ns or 0)
        if view is not self.keyframe:
            self.keyframe = view
            self.keyframe_prepared = False
        self.keyframe_deskewed = True
        self.keyframe_pose = self.pose.copy()
        self.keyframe_uncertainty = self.uncertainty
        self.scans_after_keyframe = 0
        return view

    def _keyframe_expired(self, keyframe_to_current: se2.Pose) -> bool:
        """Tell whether the current scan becomes the new reference."""
        kf = self.config.keyframes
        if kf.keyframe_distance <= 0.0 and kf.keyframe_angle <= 0.0:
            return True
        moved = float(np.hypot(keyframe_to_current[0], keyframe_to_current[1]))
        turned = abs(float(keyframe_to_current[2]))
        return ((kf.keyframe_distance > 0.0 and moved >= kf.keyframe_distance)
                or (kf.keyframe_angle > 0.0 and turned >= kf.keyframe_angle))

    def _set_keyframe(self, current: ScanPoints, motion_known: bool = True) -> None:
        """Make ``current`` the reference of the next matches.

        ``motion_known`` says whether it was de-skewed with a measured motion (not the
        first scan, not a rejected match). A scan whose sweep follows its stamp (stamped
        at the first beam) was swept during the step to the next scan, so its motion is
        only measured by the next match: that match de-skews it again.
        """
        self.keyframe = current
        self.keyframe_prepared = False
        self.keyframe_deskewed = motion_known and not sweeps_after_stamp(current)
        self.keyframe_pose = self.pose.copy()
        self.keyframe_uncertainty = self.uncertainty
        self.scans_after_keyframe = 0

    def _straighten_map_seed(self, reference: ScanPoints, twist: np.ndarray
                             ) -> ScanPoints | None:
        """Restart the local map from its first scan de-skewed with the measured ``twist``.

        The map starts from a scan whose sweep motion is not known yet (the first after a
        start or reset): it joins as it was swept, bent by the robot's motion, and every
        match against the map took the bend in. Scan to scan the reference is de-skewed
        again with the first measured twist; here the map starts again from the
        de-skewed scan. Returns the reference to match again against (the map's new
        view, or that scan when the match was made against it), or None once the first
        match is made or when the bend is :data:`MAP_SEED_BEND_CELLS` cells or less.

        Under a 5 Hz 360 deg lidar turning at 1.5 rad/s when the map started, the first
        step was 12 deg off and the next two about 3 deg (scan to scan every step within
        0.3 deg); the de-skew grid's turning rows against the map failed one step
        silently per matcher (LDS-01), integrated NEES 3500-4900 (LDS-01) and 300-3100
        (RPLidar A1): now none failed over 6 noise copies, NEES 4-14 and 76-192. The
        threshold keeps the first twist's noise out: at one cell or at the re-match
        tolerance the fast hall's first twist (ranges to 12 m) bent its seed by a few
        centimetres, and those runs took other paths (fast campus and hall, 90 runs: 7
        failed steps, 2 silent -> 12, 4); at four cells they are unchanged.
        """
        seed, self.map_seed = self.map_seed, None
        bend_allowed = MAP_SEED_BEND_CELLS * self.config.local_map.map_resolution
        if seed is None or deskew_change(seed, twist) <= bend_allowed:
            return None
        straight = deskewed(seed, twist)
        self.map_registrar.restart(straight, self.keyframe_pose)
        if reference is seed:
            return straight
        return self.map_registrar.view(self.keyframe_pose, self.last_stamp_ns or 0)
