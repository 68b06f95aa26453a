"""The simulated range finder: beam layout, timing, noise and dropouts, and scan rendering.

Readings follow REP-117: ``+inf`` when nothing is within ``max_range``, ``-inf`` when
the surface is closer than ``min_range``, and dropouts (spurious failed readings)
take ``dropout_value`` (NaN by default).

By default a scan is instantaneous: every beam is taken at the stamp, from one pose,
and ``time_increment`` is 0. A sweeping model (``sweep=True``) is a rotating lidar
that turns once per scan: beam ``i`` is taken ``i * time_increment`` after the first
beam, with ``time_increment = scan_time / beams_per_revolution``, from the pose the
robot has at that instant. The header stamp is the time of the first beam (what the
ROS drivers publish) or, with ``stamp_at='last'``, of the last one. A reversed
(clockwise) sweep has a negative ``angle_increment``, its first beam at the highest
angle.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from laser_odom.core import se2
from laser_odom.core.scan.laser_scan import LaserMounting, LaserScan
from laser_odom.core.simulation.motions import Motion
from laser_odom.core.simulation.raycast import cast_fan, cast_rays_from
from laser_odom.core.simulation.world import get_world, World

FULL_CIRCLE_EPS = 1e-9

STAMP_AT = ('first', 'last')
"""Which beam a scan's header stamp belongs to (``LaserModel.stamp_at``)."""


@dataclass(frozen=True)
class LaserModel:
    """Beam layout and error model of the simulated scanner.

    With a full 360 deg field of view the ``beams`` are spread ``fov / beams`` apart
    (the last beam does not repeat the first); with a smaller field of view the first
    and last beams lie on its edges, ``fov / (beams - 1)`` apart.
    ``angle_min`` is the lowest beam angle and defaults to ``-fov / 2`` (centred on the
    laser's x axis); a reversed sweep covers the same angles from the highest down, so
    its scans' ``angle_min`` (the first beam) is the highest.
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
    sweep: bool = False
    """Take the beams one after another over the scan (a rotating lidar), not at once."""
    reverse: bool = False
    """Sweep clockwise: negative ``angle_increment``, the first beam at the highest angle."""
    stamp_at: str = 'first'
    """The beam whose time is the header stamp: ``'first'`` (ROS drivers) or ``'last'``."""

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
        if self.stamp_at not in STAMP_AT:
            raise ValueError(f'stamp_at must be one of {", ".join(STAMP_AT)}, '
                             f'not {self.stamp_at!r}')

    @property
    def full_circle(self) -> bool:
        """Tell whether the beams cover the whole circle."""
        return self.fov >= 2.0 * math.pi - FULL_CIRCLE_EPS

    @property
    def angle_step(self) -> float:
        """Angle between neighbouring beams [rad], positive whatever the sweep direction."""
        return self.fov / (self.beams if self.full_circle else self.beams - 1)

    @property
    def angle_increment(self) -> float:
        """Angle from one beam to the next [rad]: negative for a reversed sweep."""
        return -self.angle_step if self.reverse else self.angle_step

    @property
    def lowest_angle(self) -> float:
        """Lowest beam angle [rad]."""
        return -0.5 * self.fov if self.angle_min is None else self.angle_min

    @property
    def first_angle(self) -> float:
        """Angle of the first beam [rad] (the highest one for a reversed sweep)."""
        if self.reverse:
            return self.lowest_angle + (self.beams - 1) * self.angle_step
        return self.lowest_angle

    @property
    def scan_time(self) -> float:
        """Time from one scan to the next, one revolution of a rotating lidar [s]."""
        return 1.0 / self.rate

    @property
    def beams_per_revolution(self) -> float:
        """Beams a full turn would hold at this beam spacing: ``2 pi / |angle_increment|``."""
        return 2.0 * math.pi / self.angle_step

    @property
    def time_increment(self) -> float:
        """Time between two beams [s]: ``scan_time / beams_per_revolution``, 0 if instantaneous."""
        return self.scan_time / self.beams_per_revolution if self.sweep else 0.0

    @property
    def sweep_time(self) -> float:
        """Time from the first beam to the last [s] (0 for an instantaneous scan)."""
        return (self.beams - 1) * self.time_increment

    @property
    def beam_times(self) -> np.ndarray:
        """Time of every beam relative to the header stamp [s] (all 0 if instantaneous).

        ``i * time_increment`` when stamped at the first beam, ``-(beams - 1 - i) *
        time_increment`` when stamped at the last.
        """
        index = np.arange(self.beams, dtype=float)
        if self.stamp_at == 'last':
            index -= self.beams - 1
        return index * self.time_increment

    @property
    def angles(self) -> np.ndarray:
        """Angles of all beams in the laser frame [rad]."""
        return self.first_angle + np.arange(self.beams) * self.angle_increment


def laser_world_pose(base_pose: se2.Pose, mounting: LaserMounting | None) -> se2.Pose:
    """Return the laser's pose in the world: ``base_pose * mounting``."""
    if mounting is None:
        return np.asarray(base_pose, dtype=float)
    return se2.compose(np.asarray(base_pose, dtype=float), mounting.pose)


def laser_world_poses(base_poses: np.ndarray, mounting: LaserMounting | None) -> np.ndarray:
    """Return the laser's poses (N, 3) in the world for base poses (N, 3), vectorised."""
    base = np.asarray(base_poses, dtype=float).reshape(-1, 3)
    if mounting is None:
        return base
    c, s = np.cos(base[:, 2]), np.sin(base[:, 2])
    return np.column_stack((base[:, 0] + c * mounting.x - s * mounting.y,
                            base[:, 1] + s * mounting.x + c * mounting.y,
                            se2.wrap_angle(base[:, 2] + mounting.yaw)))


def beam_base_poses(motion: Motion, stamp: float, laser: LaserModel) -> np.ndarray:
    """Return the base pose (beams, 3) at each beam's time for a scan stamped ``stamp``.

    ``stamp`` is in seconds on the clock of ``motion`` (anything with ``poses_at``,
    e.g. a :class:`~laser_odom.core.simulation.trajectory.SmoothPath`).
    """
    return np.asarray(motion.poses_at(stamp + laser.beam_times), dtype=float)


def true_ranges(world: World | str, base_pose: se2.Pose | np.ndarray,
                laser: LaserModel = LaserModel(),
                mounting: LaserMounting | None = None) -> np.ndarray:
    """Return the exact distance along every beam to the nearest wall (``inf``: none).

    ``base_pose`` is one pose (3,) for all beams, or one per beam (beams, 3) for a
    scan swept while the robot moves (see :func:`beam_base_poses`); beam ``i`` is then
    cast from ``base_pose[i] * mounting``.
    An upside-down laser is mirrored: its beam at angle ``a`` looks along ``-a`` in
    the un-flipped frame, matching :func:`laser_odom.core.scan.laser_scan.scan_to_points`.
    """
    w = get_world(world) if isinstance(world, str) else world
    sign = -1.0 if mounting is not None and mounting.upside_down else 1.0
    poses = np.asarray(base_pose, dtype=float)
    if poses.ndim == 2:
        if poses.shape != (laser.beams, 3):
            raise ValueError(f'need one pose per beam ({laser.beams}, 3), got {poses.shape}')
        origins = laser_world_poses(poses, mounting)
        angles = (origins[:, 2] + sign * laser.first_angle) + (
            np.arange(laser.beams) * (sign * laser.angle_increment))
        return cast_rays_from(origins[:, :2], angles, w.segments, laser.max_range)
    origin = laser_world_pose(poses, mounting)
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


def render_scan(world: World | str, pose: se2.Pose | np.ndarray,
                laser: LaserModel = LaserModel(), rng: np.random.Generator | None = None,
                stamp_ns: int = 0, mounting: LaserMounting | None = None) -> LaserScan:
    """Return the scan the laser sees with the robot base at ``pose`` in ``world``.

    ``pose`` is one base pose (3,), or one per beam (beams, 3) for a scan swept while
    the robot moves (:func:`beam_base_poses`; :func:`render_swept_scan` does both).
    ``mounting`` places the laser on the base (default: laser frame = base frame).
    ``rng`` draws the noise and dropouts (default: a generator seeded with 0, so a
    call is reproducible); use ``noise_sigma=0, dropout=0`` for exact ranges. The
    scan's ``time_increment`` and ``scan_time`` are the model's.
    """
    rng = np.random.default_rng(0) if rng is None else rng
    ranges = corrupt_ranges(true_ranges(world, pose, laser, mounting), laser, rng)
    intensities = np.where(np.isfinite(ranges), 100.0, 0.0)
    inc = laser.angle_increment
    return LaserScan(
        stamp_ns=int(stamp_ns), angle_min=laser.first_angle,
        angle_max=laser.first_angle + (laser.beams - 1) * inc, angle_increment=inc,
        range_min=laser.min_range, range_max=laser.max_range, ranges=ranges,
        intensities=intensities, frame_id=laser.frame_id,
        time_increment=laser.time_increment, scan_time=laser.scan_time)


def render_swept_scan(world: World | str, motion: Motion, stamp: float,
                      laser: LaserModel = LaserModel(), rng: np.random.Generator | None = None,
                      stamp_ns: int = 0, mounting: LaserMounting | None = None) -> LaserScan:
    """Return the scan stamped ``stamp`` [s on ``motion``'s clock] while the robot drives.

    Each beam is cast from the pose ``motion`` gives at the beam's own time (the
    pose at ``stamp`` for every beam if the model is instantaneous). ``stamp_ns`` is
    the header stamp written into the scan.
    """
    if not laser.sweep:
        return render_scan(world, motion.poses_at(np.array([stamp]))[0], laser, rng,
                           stamp_ns, mounting)
    return render_scan(world, beam_base_poses(motion, stamp, laser), laser, rng, stamp_ns,
                       mounting)
