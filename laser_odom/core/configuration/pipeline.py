"""Configuration of the odometry pipeline, grouped by concern.

Each group is a dataclass whose fields are declared parameters (see
:mod:`laser_odom.core.parameters`); the ROS parameter name of a field is its field name,
and matcher settings live under ``<matcher>.<field>``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Any, Mapping

from laser_odom.core.matchers import default_config, matcher_names, MatcherConfig
from laser_odom.core.parameters import param, ParameterError, replace_checked
from laser_odom.core.scan.laser_scan import LaserMounting
from laser_odom.core.search import SearchWindow

PRIORS = ('none', 'constant_velocity', 'odom', 'imu')
"""Motion priors: ``none`` starts every match at zero motion."""

VELOCITY_UPDATES = ('replace', 'weighed')
"""How a step that is not well constrained sets the velocity (:class:`MotionConfig`)."""

SEARCH_MODES = ('off', 'recover', 'always')
"""When the global search runs: never, when the prediction cannot be trusted or the
local match failed, or before every match."""

DEFAULT_MATCHER = 'nicp'
"""The matcher with the best real-log figures (README, "which matcher")."""


@dataclass
class ScanConfig:
    """Which scans and readings are used."""

    min_valid_points: int = param(
        20, 'Scans with fewer valid readings than this are skipped.', 3, 100000)
    max_beams: int = param(
        2000, 'Scans with more beams than this are matched on every k-th beam (the '
        'smallest k that keeps at most this many; said once): bounds the time per scan '
        '(0 = every beam).', 0, 1000000)
    deskew: str = param(
        'auto', 'Move every point to the instant of the scan stamp with the motion during '
        'the sweep (rotating lidars): auto = when the scan has a time_increment, on = also '
        'from scan_time when time_increment is 0, off = never.',
        choices=('auto', 'on', 'off'))
    scan_stamp: str = param(
        'first_beam', 'Which beam the scan header stamp belongs to: first_beam (the ROS '
        'convention) or last_beam (drivers that stamp a scan when it is complete). The '
        'published pose is the pose at the stamp.', choices=('first_beam', 'last_beam'))


@dataclass
class MountingConfig:
    """Pose of the laser on the base (base_frame <- laser frame)."""

    laser_x: float = param(0.0, 'Laser position on the base, x [m].', -10.0, 10.0)
    laser_y: float = param(0.0, 'Laser position on the base, y [m].', -10.0, 10.0)
    laser_yaw: float = param(0.0, 'Laser yaw on the base [rad].', -math.pi, math.pi)
    laser_upside_down: bool = param(
        False, 'Laser mounted upside down (roll of pi): the scan is mirrored.')

    def mounting(self) -> LaserMounting:
        """Return the mounting as a :class:`LaserMounting`."""
        return LaserMounting(self.laser_x, self.laser_y, self.laser_yaw, self.laser_upside_down)


@dataclass
class MotionConfig:
    """Where each match's initial guess comes from."""

    prior: str = param(
        'constant_velocity', 'Initial guess of each match: none, constant_velocity, '
        'odom (wheel odometry) or imu (yaw from an IMU).', choices=PRIORS)
    max_scan_gap: float = param(
        1.0, 'A gap between scans longer than this [s] drops the motion prior (the next '
        'match is not predicted; the global search recovers it), unless it is wheel '
        'odometry (prior: odom), which measures the motion over any gap.', 0.0, 3600.0)
    velocity_update: str = param(
        'replace', 'How a step that is not well constrained (degenerate) sets the constant '
        'velocity: replace (the step becomes the velocity) or weighed (the prediction '
        'corrected by what the scans measured of the step, each weighed by its error; for '
        'a robot that moves steadily among repeating structure, such as a hall of pillars; '
        'it costs failed steps where the motion changes abruptly between scans).',
        choices=VELOCITY_UPDATES)


@dataclass
class AcceptanceConfig:
    """When a match is trusted, and what happens when it is not."""

    min_inlier_ratio: float = param(
        0.3, 'Reject matches whose fraction of paired points is below this.', 0.0, 1.0)
    max_correction_linear: float = param(
        0.5, 'A match that moves this far [m] from a trusted prediction has failed (it '
        'is rejected, or checked by the global search).', 0.0, 100.0)
    max_correction_angular: float = param(
        0.5, 'A match that turns this far [rad] from a trusted prediction has failed (it '
        'is rejected, or checked by the global search).', 0.0, math.pi)
    max_residual_ratio: float = param(
        3.0, 'A match whose residual exceeds this multiple of the median residual of the '
        'recent accepted matches is checked by the global search (0 = never).',
        0.0, 1000.0)
    min_relative_inlier_ratio: float = param(
        0.75, 'A match that pairs less than this fraction of the median inlier ratio of '
        'the recent accepted matches is checked by the global search (a scan that slid '
        'along a wall from a wrong prediction fits well, but only in part; 0 = never).',
        0.0, 1.0)
    rejected_motion: str = param(
        'predict', 'On a rejected match: predict (advance by the prior) or hold (no motion).',
        choices=('predict', 'hold'))
    degeneracy_min_information: float = param(
        400.0, 'A direction whose match information is below this [1/m^2; rotation '
        "measured as the arc at the scan's RMS range] is degenerate (400 = a standard "
        'deviation above 5 cm, a whole step at walking speed) and takes the prediction.',
        0.0, 1e12)


@dataclass
class GlobalSearchConfig:
    """The correlative global search in front of the matcher (Olson, ICRA 2009)."""

    global_search: str = param(
        'recover', 'Correlative search of the whole window before the matcher: off, '
        'recover (when the prediction is not trusted - first match, gap, prior none, '
        'after a rejection - or the local match failed) or always.', choices=SEARCH_MODES)
    global_search_linear: float = param(
        1.5, 'Half-width [m] of the searched window in x and y, around the prediction.',
        0.0, 20.0, at_most='global_search_max_linear')
    global_search_angular: float = param(
        math.pi / 2, 'Half-width [rad] of the searched window in rotation.', 0.0, math.pi)
    global_search_resolution: float = param(
        0.1, 'Translation step [m] of the search and cell of its likelihood grid (the '
        'rotation step moves a point 10 m away by one cell).', 0.01, 1.0)
    global_search_candidates: int = param(
        3, 'The matcher refines up to this many distinct best poses of the search and '
        'keeps the one that fits best.', 1, 20)
    global_search_ambiguity: float = param(
        0.9, 'A searched match is ambiguous (reported degenerate, with a covariance '
        'that covers the alternatives) when a distinct refined pose fits at least this '
        'fraction as well (a featureless corridor, a symmetric room).', 0.5, 1.0)
    global_search_max_speed: float = param(
        1.0, 'Fastest the robot drives [m/s]: the window grows to this speed times the '
        'time since the last good match (never below global_search_linear).', 0.0, 100.0)
    global_search_max_turn_rate: float = param(
        1.5, 'Fastest the robot turns [rad/s]: the window grows to this rate times the '
        'time since the last good match (never below global_search_angular; a full turn '
        'at most).', 0.0, 100.0)
    global_search_max_linear: float = param(
        4.0, 'The window grows to at most this half-width [m], once more when the best '
        'pose lies at its edge or fits poorly (bounds the search time).', 0.0, 20.0)
    global_search_poor_fit: float = param(
        0.45, 'A searched match whose points fall on the reference surface less than this '
        '(the surface fit, 0..1) is searched again in a window twice as wide; if it still '
        'fits this poorly, its covariance covers the window (the scans cannot tell).',
        0.0, 1.0)
    global_search_effective_points: float = param(
        40.0, "The search's scores read as a likelihood (Olson 2009): a pose scoring s is "
        'exp(n (s - s_best)) as likely as the best, n this many independent points (a '
        "scan's points err together). Where that distribution spreads beyond two grid "
        'cells, the match covariance grows to cover it.', 1.0, 10000.0)

    def window(self, elapsed: float = 0.0) -> SearchWindow:
        """Return the window searched ``elapsed`` seconds after the last good match.

        Its half-widths are the configured ones, grown to the distance and turn the
        robot can cover in that time at ``global_search_max_speed`` and
        ``global_search_max_turn_rate`` (up to ``global_search_max_linear`` and a
        full turn).
        """
        linear = max(self.global_search_linear, min(
            self.global_search_max_speed * elapsed, self.global_search_max_linear))
        angular = max(self.global_search_angular, min(
            self.global_search_max_turn_rate * elapsed, math.pi))
        return SearchWindow(linear, angular, self.global_search_resolution)

    def widened(self, window: SearchWindow) -> SearchWindow | None:
        """Return ``window`` twice as wide (within the caps), None when it cannot grow."""
        linear = max(window.linear, min(2.0 * window.linear, self.global_search_max_linear))
        angular = min(2.0 * window.angular, math.pi)
        if linear <= window.linear and angular <= window.angular:
            return None
        return SearchWindow(linear, angular, window.resolution, window.sigma)


@dataclass
class KeyframeConfig:
    """Matching against a keyframe instead of the previous scan."""

    keyframe_distance: float = param(
        0.0, 'Keep matching against the last keyframe until the robot moved this far '
        '[m] (0 = scan-to-scan).', 0.0, 100.0)
    keyframe_angle: float = param(
        0.0, '...or turned this far [rad] (0 = scan-to-scan).', 0.0, math.pi)


REFERENCES = ('scan', 'local_map')
"""What each scan is matched against: the previous scan (or keyframe), or a local map."""


@dataclass
class LocalMapConfig:
    """What each scan is matched against, and the local map of recent scans."""

    reference: str = param(
        'scan', 'What each scan is matched against: scan (the previous scan, or the '
        'keyframe) or local_map (a map of the recent scans around the robot: less drift, '
        'some more time per scan; keyframe_distance and keyframe_angle do not apply).',
        choices=REFERENCES)
    map_insert_distance: float = param(
        0.1, 'A matched scan joins the local map when the robot moved this far [m] since '
        'the last scan that joined...', 0.0, 10.0)
    map_insert_angle: float = param(
        0.05, '...or turned this far [rad].', 0.0, math.pi)
    map_resolution: float = param(
        0.05, 'Cell size [m] of the local map: points within one cell are averaged.',
        0.005, 1.0)
    map_radius: float = param(
        50.0, 'The local map keeps the cells within this distance [m] of the robot.',
        1.0, 500.0)
    map_max_points: int = param(
        30000, 'Most cells the local map keeps (the longest unseen go first): bounds its '
        'memory and the time per scan.', 100, 10_000_000)
    map_max_age: int = param(
        1000, 'A cell not seen again by this many of the scans that joined the map since is '
        'dropped (about 100 m of path at the default map_insert_distance): a corridor '
        'driven again matches the walls the map kept, as a revisit re-anchors '
        "hector_mapping's grid; 50 (the last 5 m) left fr079 nicp at 0.6 % drift, "
        '1000 at 0.4 %.', 1, 1_000_000)
    map_cell_weight: int = param(
        20, 'Observations a map cell averages; beyond, older ones fade (a cell follows a '
        'changed scene).', 1, 100000)


@dataclass
class PipelineConfig:
    """Everything the odometry pipeline needs, grouped by concern."""

    matcher: str = DEFAULT_MATCHER
    matcher_config: MatcherConfig | None = None
    scan: ScanConfig = field(default_factory=ScanConfig)
    mounting: MountingConfig = field(default_factory=MountingConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    acceptance: AcceptanceConfig = field(default_factory=AcceptanceConfig)
    search: GlobalSearchConfig = field(default_factory=GlobalSearchConfig)
    keyframes: KeyframeConfig = field(default_factory=KeyframeConfig)
    local_map: LocalMapConfig = field(default_factory=LocalMapConfig)

    def resolved_matcher_config(self) -> MatcherConfig:
        """Return the matcher's configuration, its tuned defaults when unset."""
        return self.matcher_config if self.matcher_config is not None else default_config(
            self.matcher)


PIPELINE_GROUPS = ('scan', 'mounting', 'motion', 'acceptance', 'search', 'keyframes',
                   'local_map')


def pipeline_config_from_params(values: Mapping[str, Any]) -> PipelineConfig:
    """Build a :class:`PipelineConfig` from flat ROS-style parameters.

    ``values`` maps names such as ``matcher``, ``min_inlier_ratio`` or
    ``plicp.max_iterations`` to values, as found under ``ros__parameters`` in the
    node's YAML. Unknown names and bad values raise :class:`ParameterError`.
    Parameters that belong to the ROS shell only (frames, topics) are ignored.
    """
    remaining = dict(values)
    matcher = remaining.pop('matcher', DEFAULT_MATCHER)
    if matcher not in matcher_names():
        raise ParameterError(
            f'unknown matcher {matcher!r}; valid names: {", ".join(matcher_names())}')
    config = PipelineConfig(matcher=matcher)
    for group in PIPELINE_GROUPS:
        current = getattr(config, group)
        names = set(current.__dataclass_fields__)
        picked = {k: remaining.pop(k) for k in list(remaining) if k in names}
        setattr(config, group, replace_checked(current, picked))
    for name in matcher_names():
        prefix = name + '.'
        picked = {k[len(prefix):]: remaining.pop(k) for k in list(remaining)
                  if k.startswith(prefix)}
        if name == matcher:
            config.matcher_config = replace_checked(default_config(name), picked, prefix)
        else:
            replace_checked(default_config(name), picked, prefix)
    return config
