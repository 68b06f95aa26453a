"""Live reconfiguration of the odometry pipeline: new settings from the next scan on.

The node applies a ``ros2 param set``, or a laser mounting that TF tells late, between
two scans, keeping the pose: a new matcher replaces the matcher, a new mounting
restarts integration, a new ``reference`` or local-map setting starts the map again
from the last scan. A mixin of :class:`.odometry.OdometryPipeline`, kept apart from the
per-scan path; its methods use the pipeline's state (settings, matcher, registrars,
reference scan, local map) and its ``reset``.
"""

from __future__ import annotations

import numpy as np

from laser_odom.core.configuration.pipeline import PipelineConfig
from laser_odom.core.matchers import matcher_class, ScanMatcher
from laser_odom.core.preprocess.validation import ScanValidator


class LiveReconfiguration:
    """Matcher switches, :meth:`configure` and the switch of reference."""

    def set_matcher(self, matcher: ScanMatcher) -> None:
        """Switch the matcher; the pose and the reference scan are kept."""
        if matcher.name != self.matcher.name:
            self.registrar.usual.clear()
        self.matcher = matcher
        self.config.matcher = matcher.name
        self.config.matcher_config = matcher.config

    def configure(self, config: PipelineConfig) -> None:
        """Apply new settings from the next scan on, keeping the pose (live reconfiguration).

        A new matcher or matcher setting replaces the matcher (:meth:`set_matcher`). A new
        laser mounting changes every base-frame point, so the reference scan is dropped and
        integration restarts from the current pose. A new ``reference`` or local-map
        setting starts the map again from the last scan (:meth:`_switch_reference`);
        other settings keep the reference.
        """
        mounting_changed = config.mounting != self.config.mounting
        map_changed = config.local_map != self.config.local_map
        matcher_config = config.resolved_matcher_config()
        if config.matcher != self.matcher.name or matcher_config != self.matcher.config:
            matcher = matcher_class(config.matcher)(matcher_config)
        else:
            matcher = self.matcher
        self.config = config
        self.set_matcher(matcher)
        self.validator = ScanValidator(config.scan, config.mounting, self.events)
        self.motion.config = config.motion
        if mounting_changed:
            self.map_registrar = self._map_registrar(config)
            self.reset(self.pose, self.pose_covariance)
        elif map_changed:
            self._switch_reference(config)

    def _switch_reference(self, config: PipelineConfig) -> None:
        """Match against a new local map, or the previous scan, from the next scan on.

        The last scan, at the current pose, is the first scan of the new map, or the
        reference scan when the map is left; the motion to the next scan is matched
        as usual. Without such a scan (none yet, or a keyframe behind the current
        pose) integration restarts from the current pose.
        """
        if self.map_registrar is not None:  # the map's previous scan: at the current pose
            last = self.map_registrar.map.previous_scan
            at_pose = last is not None
        else:
            last = self.keyframe
            at_pose = last is not None and np.array_equal(self.keyframe_pose, self.pose)
        self.map_registrar = self._map_registrar(config)
        self.mid_sweep_twist.forget()  # its poses were anchored on the old reference
        if not at_pose:
            self.reset(self.pose, self.pose_covariance)
        elif self.map_registrar is not None:
            self.map_registrar.restart(last, self.pose)
            self.keyframe_prepared = False
        else:
            self._set_keyframe(last)
