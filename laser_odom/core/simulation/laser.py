"""The simulated range finder: beam layout, noise and dropouts, and single-scan rendering.

Readings follow REP-117: ``+inf`` when nothing is within ``max_range``, ``-inf`` when
the surface is closer than ``min_range``, and dropouts (spurious failed readings)
take ``dropout_value`` (NaN by default). Scans are rendered instantaneously (no motion
during the sweep), hence ``time_increment`` is 0.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from laser_odom.core import se2
from laser_odom.core.scan import LaserMounting, LaserScan
from laser_odom.core.simulation.raycast import cast_fan
from laser_odom.core.simulation.world import get_world, World

FULL_CIRCLE_EPS = 1e-9


@dataclass(frozen=True)
class LaserModel:
    """Beam layout and error model of the simulated scanner.

    With a full 360 deg field of view the ``beams`` are spread ``fov / beams`` apart
    (the last beam does not repeat the first); with a smaller field of view the first
    and last beams lie on its edges, ``fov / (beams - 1)`` apart.
    ``angle_min`` defaults to ``-fov / 2`` (centred on the laser's x axis).
    """

    beams: int = 360
    fov: float = 2.0 * math.pi
    angle_min: float | None = None
    max_range: float = 20.0
    min_range: float = 0.05
    noise_sigma: float = 0.01
    """Standard deviation of the Gaussian range noise [m]."""
    dropout: float = 0.0
    """Probability that a reading is replaced by ``dropout_value``."""
    dropout_value: float = float('nan')
    rate: float = 10.0
    """Scan rate [Hz]."""
    frame_id: str = 'laser'

    def __post_init__(self) -> None:
        """Reject layouts and error models that cannot be simulated."""
        if self.beams < 2:
            raise ValueError('a laser needs at least 2 beams')
        if not 0.0 < self.fov <= 2.0 * math.pi + FULL_CIRCLE_EPS:
            raise ValueError('field of view must be in (0, 2 pi]')
        if not 0.0 <= self.min_range < self.max_range:
            raise ValueError('need 0 <= min_range < max_range')
        if self.noise_sigma < 0.0 or not 0.0 <= self.dropout <= 1.0:
            raise ValueError('noise must be >= 0 and dropout in [0, 1]')
        if self.rate <= 0.0:
            raise ValueError('scan rate must be positive')

    @property
    def full_circle(self) -> bool:
        """Tell whether the beams cover the whole circle."""
        return self.fov >= 2.0 * math.pi - FULL_CIRCLE_EPS

    @property
    def angle_increment(self) -> float:
        """Angle between neighbouring beams [rad]."""
        return self.fov / (self.beams if self.full_circle else self.beams - 1)

    @property
    def first_angle(self) -> float:
        """Angle of the first beam [rad]."""
        return -0.5 * self.fov if self.angle_min is None else self.angle_min

    @property
    def angles(self) -> np.ndarray:
        """Angles of all beams in the laser frame [rad]."""
        return self.first_angle + np.arange(self.beams) * self.angle_increment


def laser_world_pose(base_pose: se2.Pose, mounting: LaserMounting | None) -> se2.Pose:
    """Return the laser's pose in the world: ``base_pose * mounting``."""
    if mounting is None:
        return np.asarray(base_pose, dtype=float)
    return se2.compose(np.asarray(base_pose, dtype=float), mounting.pose)


def true_ranges(world: World | str, base_pose: se2.Pose, laser: LaserModel = LaserModel(),
                mounting: LaserMounting | None = None) -> np.ndarray:
    """Return the exact distance along every beam to the nearest wall (``inf``: none).

    An upside-down laser is mirrored: its beam at angle ``a`` looks along ``-a`` in
    the un-flipped frame, matching :func:`laser_odom.core.scan.scan_to_points`.
    """
    w = get_world(world) if isinstance(world, str) else world
    origin = laser_world_pose(base_pose, mounting)
    sign = -1.0 if mounting is not None and mounting.upside_down else 1.0
    return cast_fan(origin[:2], origin[2] + sign * laser.first_angle,
                    sign * laser.angle_increment, laser.beams, w.segments, laser.max_range)


def corrupt_ranges(ranges: np.ndarray, laser: LaserModel,
                   rng: np.random.Generator) -> np.ndarray:
    """Add Gaussian noise and dropouts, then apply the REP-117 out-of-range codes."""
    out = np.array(ranges, dtype=float)
    hit = np.isfinite(out)
    noise = rng.standard_normal(out.shape[0]) * laser.noise_sigma
    drop = rng.random(out.shape[0]) < laser.dropout
    out[hit] += noise[hit]
    out[hit & (out > laser.max_range)] = np.inf
    out[hit & (out < laser.min_range)] = -np.inf
    out[drop] = laser.dropout_value
    return out


def render_scan(world: World | str, pose: se2.Pose, laser: LaserModel = LaserModel(),
                rng: np.random.Generator | None = None, stamp_ns: int = 0,
                mounting: LaserMounting | None = None) -> LaserScan:
    """Return the scan the laser sees with the robot base at ``pose`` in ``world``.

    ``mounting`` places the laser on the base (default: laser frame = base frame).
    ``rng`` draws the noise and dropouts (default: a generator seeded with 0, so a
    call is reproducible); use ``noise_sigma=0, dropout=0`` for exact ranges.
    """
    rng = np.random.default_rng(0) if rng is None else rng
    ranges = corrupt_ranges(true_ranges(world, pose, laser, mounting), laser, rng)
    intensities = np.where(np.isfinite(ranges), 100.0, 0.0)
    inc = laser.angle_increment
    return LaserScan(
        stamp_ns=int(stamp_ns), angle_min=laser.first_angle,
        angle_max=laser.first_angle + (laser.beams - 1) * inc, angle_increment=inc,
        range_min=laser.min_range, range_max=laser.max_range, ranges=ranges,
        intensities=intensities, frame_id=laser.frame_id, time_increment=0.0,
        scan_time=1.0 / laser.rate)
