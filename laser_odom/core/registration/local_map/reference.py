"""The local map as the pipeline's reference: which scans join it, what a match sees.

With ``reference: local_map`` every scan is matched against a view of the local map
(:mod:`laser_odom.core.registration.local_map.map`) from the previous pose, instead of the previous
scan. Only evidence the odometry trusts builds the map: a scan joins it after a
match that was accepted and not ambiguous, once the robot has moved or turned enough
since the last scan that joined (``map_insert_distance``, ``map_insert_angle``). A
rejected match means the map and the scan disagree beyond what the prediction
explains; as the previous scan does in scan-to-scan mode, the map then restarts from
the current scan at the predicted pose, so a wrong map costs a step, not the run.

Joining is deferred until the next view is needed (:meth:`MapReference.view`), so
that the node can do it after publishing (``prepare_next``); the result never
depends on when it happens.
"""

from __future__ import annotations

import math

import numpy as np

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import LocalMapConfig
from laser_odom.core.matchers import MatchResult
from laser_odom.core.registration.local_map.map import LocalMap, MapGeometry
from laser_odom.core.registration.local_map.surface_fit import MIN_PAIRS
from laser_odom.core.scan.laser_scan import LaserMounting, LaserScan, ScanPoints

MIN_VIEW_BIN = math.radians(0.1)
"""Finest bearing bin of a view [rad] (a scan's beam spacing, never finer)."""

MAX_VIEW_BIN = math.radians(1.0)
"""Coarsest bearing bin of a view [rad]."""

JOIN_INLIER_SHARE = 0.8
"""A match against the previous scan fits as usual when it paired at least this share
of the usual inlier ratio (a map match is not held to it: the map covers only what it
has seen)..."""

JOIN_RESIDUAL_RATIO = 2.0
"""...and its residual is at most this multiple of the usual one (map matches too: a
scan joins the map only then)."""

MAX_SURFACE_TURN = math.radians(1.0)
"""A refinement on the map's surfaces that turns the step by more is not taken."""

MAX_REFUSED = 5
"""After this many scans in a row that moved enough but fit the map too poorly to join
it, the map no longer describes the scene (it changed, or the map went wrong): it
starts again from the current scan."""


class MapReference:
    """The local map, the scans waiting to join it, and the view the next match uses."""

    def __init__(self, config: LocalMapConfig, mounting: LaserMounting) -> None:
        """Create an empty map with ``config``'s geometry; the laser sits at ``mounting``."""
        self.config = config
        self.sensor = np.array([mounting.x, mounting.y], dtype=float)
        self.map = LocalMap(MapGeometry(config.map_resolution, config.map_radius,
                                        config.map_max_points, float(config.map_cell_weight),
                                        config.map_max_age))
        self.bin_angle = math.radians(0.5)
        self.max_range = config.map_radius
        self.reset()

    def reset(self) -> None:
        """Forget the map (a start, a reset, a time jump)."""
        self.map.clear()
        self._pending: tuple[np.ndarray, np.ndarray] | None = None
        self._last_joined: np.ndarray | None = None
        self._view: tuple[np.ndarray, ScanPoints] | None = None
        self.joined = 0
        self.refused = 0
        self.previous_scan: ScanPoints | None = None

    @property
    def empty(self) -> bool:
        """Tell whether nothing has joined the map since the last reset."""
        return self._pending is None and len(self.map) == 0

    def observe_scan(self, scan: LaserScan) -> None:
        """Take the view's bearing bin and reach from the laser's own geometry."""
        spacing = abs(scan.angle_increment)
        if spacing > 0.0 and math.isfinite(spacing):
            self.bin_angle = min(max(spacing, MIN_VIEW_BIN), MAX_VIEW_BIN)
        if scan.range_max > 0.0 and math.isfinite(scan.range_max):
            self.max_range = min(scan.range_max, self.config.map_radius)

    def offer(self, scan: ScanPoints, pose: se2.Pose, fits: bool = True,
              force: bool = False) -> str:
        """Let an accepted scan join the map at ``pose`` if the robot moved enough.

        ``fits`` says whether its match fitted the map about as well as accepted
        matches usually do (:func:`fits_usual`, not ambiguous, not taken from the
        previous scan instead): a pose that is accepted but fits poorly may be wrong,
        and a wrong scan in the map would mislead every later match. After
        :data:`MAX_REFUSED` such scans in a row the map starts again from this one.
        ``force`` joins it whatever the motion and fit (the first scan after a
        restart). Returns what became of it: ``'joined'``, ``'near'`` (too close to
        the last scan that joined), ``'refused'`` or ``'restarted'`` (the map starts
        again from it). The scan is kept as the previous scan in any case (the second
        opinion of the next match).
        """
        self.previous_scan = scan
        if not force and self._last_joined is not None:
            moved = se2.relative(self._last_joined, pose)
            if (math.hypot(moved[0], moved[1]) < self.config.map_insert_distance
                    and abs(moved[2]) < self.config.map_insert_angle):
                return 'near'
        outcome = 'joined'
        if not force and not fits:
            self.refused += 1
            if self.refused < MAX_REFUSED:
                return 'refused'
            self.reset()
            self.previous_scan = scan
            outcome = 'restarted'
        self.refused = 0
        self._flush()
        self._pending = (np.array(scan.points, dtype=float), np.array(pose, dtype=float))
        self._last_joined = np.array(pose, dtype=float)
        self._view = None
        return outcome

    def restart(self, scan: ScanPoints, pose: se2.Pose) -> None:
        """Start the map again from one scan at ``pose`` (the first, or after a rejection)."""
        self.reset()
        self.offer(scan, pose, force=True)

    def view(self, pose: se2.Pose, stamp_ns: int = 0) -> ScanPoints:
        """Return the map seen from base ``pose``, in that pose's frame (cached per pose)."""
        self._flush()
        pose = np.asarray(pose, dtype=float)
        if self._view is not None and np.array_equal(self._view[0], pose):
            return self._view[1]
        view = self.map.view(pose, self.sensor, self.bin_angle, self.max_range,
                             stamp_ns=stamp_ns)
        self._view = (pose.copy(), view)
        return view

    def refine_step(self, points: np.ndarray, view_pose: se2.Pose, step: se2.Pose,
                    weak_share: float = 0.0) -> np.ndarray | None:
        """Refine a matched ``step`` from ``view_pose`` on the map's own surfaces.

        :mod:`.local_map.surface_fit`; returns the refined step, None when too few of
        the scan's ``points`` lie on surfaces of the map or the refinement moved the
        step by more than a cell (``map_resolution``) or :data:`MAX_SURFACE_TURN`: each
        point pairs within a cell and a half, so a larger move changed the pairing and
        found another minimum, not a finer one (fr079, imls: 99 % of the refinements
        move less than 5 cm and 0.9 deg, a few slid by 0.25-0.33 m).
        """
        self._flush()
        view_pose = np.asarray(view_pose, dtype=float)
        pose, pairs = self.map.fit_to_surfaces(points, se2.compose(view_pose, step),
                                               weak_share)
        refined = np.asarray(se2.relative(view_pose, pose), dtype=float)
        moved = se2.relative(step, refined)
        if (pairs < MIN_PAIRS or math.hypot(moved[0], moved[1]) > self.config.map_resolution
                or abs(moved[2]) > MAX_SURFACE_TURN):
            return None
        return refined

    def _flush(self) -> None:
        """Insert the scan waiting to join."""
        if self._pending is None:
            return
        points, pose = self._pending
        self._pending = None
        self.map.insert(points, pose, self.sensor, self.bin_angle)
        self.joined += 1


def fits_usual(match: MatchResult, usual_residual: float | None,
               usual_inliers: float | None) -> bool:
    """Tell whether a match fits about as well as accepted matches usually do.

    At least :data:`JOIN_INLIER_SHARE` of the usual inlier ratio, and at most
    :data:`JOIN_RESIDUAL_RATIO` times the usual residual (either test is skipped
    while its usual level is not known yet, or given as None: a match against the
    map, whose coverage of the scan is no measure of its pose).
    """
    if usual_inliers is not None and match.inlier_ratio < JOIN_INLIER_SHARE * usual_inliers:
        return False
    return not (usual_residual is not None
                and match.residual > JOIN_RESIDUAL_RATIO * usual_residual)
