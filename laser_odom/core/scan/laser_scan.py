"""Laser scans as plain data, and their conversion to 2D point sets.

``LaserScan`` mirrors the fields of ``sensor_msgs/LaserScan`` without depending on
ROS, so the core, the node and the replay harness share one representation.
``ScanPoints`` is the matcher's view of a scan: finite points in the base frame in
beam order, with a lazily built nearest-neighbour index (by bearing) and a cache for
per-scan derived data (normals, curvature) so that each is computed once per scan even
though a scan is first the current scan and then the reference of the next match.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
import math
from typing import Any

import numba
import numpy as np

from laser_odom.core import se2
from laser_odom.core.scan.nearest import BearingIndex

MAX_DENSE_POINTS = 20000
"""Upper bound on the points a densified surface adds (bounds time on huge scans)."""


@dataclass
class LaserScan:
    """The fields of a ``sensor_msgs/LaserScan``, stamp in integer nanoseconds."""

    stamp_ns: int
    angle_min: float
    angle_max: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: np.ndarray
    intensities: np.ndarray | None = None
    frame_id: str = 'laser'
    time_increment: float = 0.0
    scan_time: float = 0.0

    @property
    def stamp(self) -> float:
        """Stamp in seconds."""
        return self.stamp_ns * 1e-9


@dataclass(frozen=True)
class LaserMounting:
    """Pose of the laser on the robot base (``base_frame`` <- laser ``frame_id``).

    ``upside_down`` is a roll of pi about the laser's x axis: it mirrors the scan
    (y -> -y in the laser frame) before the planar mounting pose is applied.
    """

    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    upside_down: bool = False

    @property
    def pose(self) -> se2.Pose:
        """Planar part of the mounting as an SE(2) pose."""
        return se2.pose(self.x, self.y, self.yaw)

    @property
    def is_identity(self) -> bool:
        """Tell whether the laser frame coincides with the base frame."""
        return not self.upside_down and self.x == 0.0 and self.y == 0.0 and self.yaw == 0.0


@dataclass(eq=False)
class ScanPoints:
    """Finite 2D points of one scan, in the base frame and in beam order.

    ``beam_index`` holds each point's index in the original ``ranges`` array, so
    matchers that need beam adjacency (PL-ICP) can tell true neighbours from points
    that are adjacent only because invalid beams between them were dropped.
    ``times`` [s, relative to the stamp] are the beams' measurement times when the scan
    is de-skewed; ``measured`` then holds the points as measured, and ``twist`` the
    twist they were de-skewed with (:mod:`laser_odom.core.preprocess.deskew`). A virtual scan of
    the local map (:mod:`laser_odom.core.registration.local_map.map`) numbers its bearing
    bins as beams.
    """

    points: np.ndarray
    beam_index: np.ndarray
    ranges: np.ndarray
    stamp_ns: int = 0
    cache: dict[Any, Any] = field(default_factory=dict, repr=False)
    times: np.ndarray | None = None
    measured: np.ndarray | None = None
    twist: np.ndarray | None = None
    virtual: bool = False
    """A view of the local map rendered as a scan, not a measured scan."""

    def __len__(self) -> int:
        """Return the number of points."""
        return int(self.points.shape[0])

    @cached_property
    def length_scale(self) -> float:
        """RMS distance of the points from the sensor [m]: how far a rotation moves them."""
        if len(self) == 0:
            return 1.0
        return math.sqrt(float(np.einsum('nd,nd->', self.points, self.points)) / len(self))

    @cached_property
    def bearing_index(self) -> BearingIndex:
        """The points sorted by bearing, for exact gated nearest-neighbour search."""
        return BearingIndex(self.points)


def beam_angles(scan: LaserScan, count: int | None = None) -> np.ndarray:
    """Return the angle of every beam: ``angle_min + i * angle_increment``.

    Negative increments (scanners that sweep clockwise) give decreasing angles.
    """
    n = len(scan.ranges) if count is None else count
    return scan.angle_min + np.arange(n, dtype=float) * scan.angle_increment


def valid_range_mask(ranges: np.ndarray, range_min: float, range_max: float) -> np.ndarray:
    """Return the readings that are finite and inside [range_min, range_max] (REP-117)."""
    with np.errstate(invalid='ignore'):
        return np.isfinite(ranges) & (ranges >= range_min) & (ranges <= range_max)


def scan_to_points(scan: LaserScan, mounting: LaserMounting | None = None) -> ScanPoints:
    """Convert a scan to finite 2D points in the base frame, vectorised.

    NaN, inf and out-of-range readings are dropped; the surviving points keep beam
    order and their original beam indices.
    """
    ranges = np.asarray(scan.ranges, dtype=float)
    keep = valid_range_mask(ranges, scan.range_min, scan.range_max)
    index = np.flatnonzero(keep)
    r = ranges[index]
    angles = scan.angle_min + index * scan.angle_increment
    points = np.column_stack((r * np.cos(angles), r * np.sin(angles)))
    if mounting is not None and not mounting.is_identity:
        if mounting.upside_down:
            points[:, 1] = -points[:, 1]
        points = se2.transform_points(mounting.pose, points)
    return ScanPoints(points=points, beam_index=index, ranges=r, stamp_ns=scan.stamp_ns)


def densify(scan: ScanPoints, spacing: float, max_gap: float,
            gap_per_range: float = 0.0) -> np.ndarray:
    """Return the scan's points plus points interpolated along its surface.

    Consecutive beams closer than ``max_gap`` are taken to lie on one surface and the
    segment between them is filled every ``spacing`` metres. Point-to-point pairs then
    land near the true surface point instead of the nearest beam sample, which removes
    most of ICP's sampling bias (the reason PL-ICP uses lines instead, Censi 2008).
    With ``gap_per_range`` > 0, beams up to ``gap_per_range * r * dalpha`` apart (``r``
    the nearer range, ``dalpha`` the angle between the beams) also count as one surface:
    far walls are sampled sparsely but are still walls. The spacing widens if the
    surface would need more than ``MAX_DENSE_POINTS``.
    """
    points = scan.points
    if spacing <= 0.0 or len(points) < 2:
        return points
    return _densify(np.ascontiguousarray(points, dtype=float),
                    np.asarray(scan.beam_index, dtype=np.int64),
                    np.asarray(scan.ranges, dtype=float), float(spacing), float(max_gap),
                    float(gap_per_range), float(MAX_DENSE_POINTS))


@numba.njit(cache=True, nogil=True)
def _densify(points: np.ndarray, beam_index: np.ndarray, ranges: np.ndarray, spacing: float,
             max_gap: float, gap_per_range: float, max_points: float) -> np.ndarray:
    """Compiled :func:`densify`: the scan's points, then each segment's inserted points."""
    segments = points.shape[0] - 1
    length = np.empty(segments)
    on_surface = np.zeros(segments, dtype=np.bool_)
    total = 0.0
    for i in range(segments):
        ax, ay, bx, by = points[i, 0], points[i, 1], points[i + 1, 0], points[i + 1, 1]
        length[i] = math.hypot(bx - ax, by - ay)
        limit = max_gap
        if gap_per_range > 0.0:
            apart = abs(math.atan2(ax * by - ay * bx, ax * bx + ay * by))
            limit = max(limit, gap_per_range * min(ranges[i], ranges[i + 1]) * apart)
        on_surface[i] = (beam_index[i + 1] - beam_index[i] == 1 and length[i] < limit
                         and math.isfinite(length[i]))
        if on_surface[i]:
            total += length[i]
    spacing = max(spacing, total / max_points)
    inserted = np.zeros(segments, dtype=np.int64)
    for i in range(segments):
        if on_surface[i]:  # the cap keeps the count an integer for any length
            inserted[i] = max(math.ceil(min(length[i] / spacing, max_points) - 1e-9) - 1, 0)
    dense = np.empty((points.shape[0] + inserted.sum(), 2))
    dense[:points.shape[0]] = points
    k = points.shape[0]
    for i in range(segments):
        for rank in range(inserted[i]):
            fraction = (rank + 1.0) / (inserted[i] + 1.0)
            dense[k, 0] = points[i, 0] + (points[i + 1, 0] - points[i, 0]) * fraction
            dense[k, 1] = points[i, 1] + (points[i + 1, 1] - points[i, 1]) * fraction
            k += 1
    return dense
