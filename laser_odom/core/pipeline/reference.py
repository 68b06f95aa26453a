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
from laser_odom.core.preprocess.deskew import sweeps_after_stamp
from laser_odom.core.scan.laser_scan import ScanPoints


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
