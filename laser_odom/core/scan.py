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
from typing import Any

import numpy as np

from laser_odom.core import se2
from laser_odom.core.nearest import BearingIndex

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
    twist they were de-skewed with (:mod:`laser_odom.core.deskew`).
    """

    points: np.ndarray
    beam_index: np.ndarray
    ranges: np.ndarray
    stamp_ns: int = 0
    cache: dict[Any, Any] = field(default_factory=dict, repr=False)
    times: np.ndarray | None = None
    measured: np.ndarray | None = None
    twist: np.ndarray | None = None

    def __len__(self) -> int:
        """Return the number of points."""
        return int(self.points.shape[0])

    @cached_property
    def length_scale(self) -> float:
        """RMS distance of the points from the sensor [m]: how far a rotation moves them."""
        if len(self) == 0:
            return 1.0
        return float(np.sqrt(np.mean(np.sum(np.square(self.points), axis=1))))

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
    segment = points[1:] - points[:-1]
    length = np.hypot(segment[:, 0], segment[:, 1])
    limit = np.full(len(segment), max_gap)
    if gap_per_range > 0.0:
        a, b = points[:-1], points[1:]
        apart = np.abs(np.arctan2(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0],
                                  np.einsum('nd,nd->n', a, b)))
        nearer = np.minimum(scan.ranges[:-1], scan.ranges[1:])
        limit = np.maximum(limit, gap_per_range * nearer * apart)
    on_surface = (np.diff(scan.beam_index) == 1) & (length < limit) & np.isfinite(length)
    spacing = max(spacing, float(length[on_surface].sum()) / MAX_DENSE_POINTS)
    per_segment = np.minimum(length / spacing, MAX_DENSE_POINTS)  # no int overflow
    inserted = np.where(on_surface,
                        np.maximum(np.ceil(per_segment - 1e-9).astype(int) - 1, 0), 0)
    owner = np.repeat(np.arange(len(segment)), inserted)
    rank = np.arange(int(inserted.sum())) - np.repeat(np.cumsum(inserted) - inserted, inserted)
    fraction = (rank + 1.0) / (inserted[owner] + 1.0)
    return np.vstack((points, points[:-1][owner] + segment[owner] * fraction[:, None]))
