"""Deterministic simulation of a robot driving a world: scans, ground truth, wheel odometry.

One seed fixes everything: it is split (``numpy.random.SeedSequence.spawn``) into
independent streams for the laser noise, the odometry noise and the dropped scans, so
changing one of them does not change the others (nor does the sensor's timing: a
sweeping model draws the same noise as the instantaneous one with the same beams).
"""

from __future__ import annotations

import math

import numpy as np

from laser_odom.core import se2
from laser_odom.core.scan.laser_scan import LaserMounting
from laser_odom.core.simulation.laser import beam_base_poses, LaserModel, render_scan
from laser_odom.core.simulation.motions import DEFAULT_MOTION, Motion, motion_profile
from laser_odom.core.simulation.odometry import OdometryNoise, wheel_odometry
from laser_odom.core.simulation.sensors import DEFAULT_SENSOR, sensor_model
from laser_odom.core.simulation.world import DEFAULT_WORLD, get_world, World
from laser_odom.core.trajectory import Dataset, Trajectory

EPOCH_NS = 1_700_000_000 * 1_000_000_000
"""Stamp of the first simulated scan [ns] (2023-11-14T22:13:20Z)."""

ODOMETRY_RATE = 50.0
"""Default rate of the simulated wheel odometry [Hz]."""


def sample_stamps(duration: float, rate: float, start_ns: int = EPOCH_NS) -> np.ndarray:
    """Return the stamps [ns] of ``round(duration * rate)`` samples at ``rate`` Hz."""
    count = max(int(round(duration * rate)), 1)
    return start_ns + np.round(np.arange(count) * (1e9 / rate)).astype(np.int64)


def simulate(world: str | World = DEFAULT_WORLD, duration: float = 60.0,
             laser: LaserModel | None = None, seed: int = 0,
             mounting: LaserMounting | None = None,
             odometry_noise: OdometryNoise = OdometryNoise(),
             odometry_rate: float = ODOMETRY_RATE, start_ns: int = EPOCH_NS,
             motion: str | Motion = DEFAULT_MOTION, drop: float = 0.0,
             sensor: str | None = None) -> Dataset:
    """Simulate ``duration`` seconds of the robot driving ``world``'s path.

    Returns a :class:`Dataset` whose ``scans`` come at ``laser.rate`` from ``start_ns``,
    whose ``reference`` is the ground-truth base pose at every scan's header stamp
    (world frame, which is also the frame of the start pose) and whose ``odometry`` is
    noisy wheel odometry at ``odometry_rate`` covering every scan stamp. The scans are
    rendered from the laser's pose ``base * mounting`` (default: laser frame = base
    frame); a sweeping ``laser`` casts each beam from the pose at the beam's own time
    (the first beam at the stamp, or the last with ``stamp_at='last'``).
    ``sensor`` names a preset of :mod:`.sensors` instead of ``laser`` (give one or the
    other; neither is the ``ideal`` instantaneous scanner, :class:`LaserModel`'s
    defaults). ``motion`` names how the robot drives (:mod:`.motions`), or is any
    object with ``poses_at`` (e.g. :class:`~.motions.ConstantTwist`); each scan but the
    first is lost with probability ``drop`` (a driver or a link dropping scans), and so
    is its reference pose.
    """
    if duration <= 0.0 or odometry_rate <= 0.0:
        raise ValueError('duration and odometry rate must be positive')
    if not 0.0 <= drop < 1.0:
        raise ValueError('the share of dropped scans must be in [0, 1)')
    if laser is not None and sensor is not None:
        raise ValueError('give a laser model or a sensor preset name, not both')
    if laser is None:
        laser = sensor_model(DEFAULT_SENSOR if sensor is None else sensor)
    w = get_world(world) if isinstance(world, str) else world
    path = motion_profile(w, motion) if isinstance(motion, str) else motion
    laser_seed, odom_seed, drop_seed = np.random.SeedSequence(seed).spawn(3)
    laser_rng = np.random.default_rng(laser_seed)
    scan_stamps = sample_stamps(duration, laser.rate, start_ns)
    times = (scan_stamps - start_ns) * 1e-9
    truth = path.poses_at(times)
    if laser.sweep:
        scans = [render_scan(w, beam_base_poses(path, times[i], laser), laser, laser_rng,
                             int(scan_stamps[i]), mounting) for i in range(len(scan_stamps))]
    else:
        scans = [render_scan(w, truth[i], laser, laser_rng, int(scan_stamps[i]), mounting)
                 for i in range(len(scan_stamps))]
    last = (scan_stamps[-1] - start_ns) * 1e-9
    odom_count = int(math.ceil(last * odometry_rate - 1e-9)) + 1
    odom_stamps = start_ns + np.round(np.arange(odom_count) * (1e9 / odometry_rate)).astype(
        np.int64)
    odom_truth = Trajectory(odom_stamps, path.poses_at((odom_stamps - start_ns) * 1e-9))
    odometry = wheel_odometry(odom_truth, odometry_noise, np.random.default_rng(odom_seed))
    kept = np.random.default_rng(drop_seed).random(len(scans)) >= drop
    kept[0] = True
    suffix = '' if motion == DEFAULT_MOTION else (
        f'-{motion}' if isinstance(motion, str) else f'-{type(motion).__name__.lower()}')
    if sensor is not None and sensor != DEFAULT_SENSOR:
        suffix += f'-{sensor}'
    return Dataset(name=f'sim-{w.name}{suffix}-seed{seed}',
                   scans=[scan for scan, keep in zip(scans, kept) if keep],
                   odometry=odometry, reference=Trajectory(scan_stamps[kept], truth[kept]))


def drop_to_steps(dataset: Dataset, distance: float, angle: float) -> Dataset:
    """Return ``dataset`` with scans dropped so that each step is as large as allowed.

    Every scan is kept whose successor would carry the robot farther than ``distance``
    [m] or turn it more than ``angle`` [rad] from the last kept scan (by the
    reference, which must hold a pose per scan): a driver, a link or a busy node that
    lost everything in between. The first scan is kept; the reference keeps the poses
    of the kept scans.
    """
    poses = dataset.reference.poses
    if len(poses) != len(dataset.scans):
        raise ValueError('dropping to steps needs a reference pose for every scan')
    kept = [0]
    for index in range(1, len(poses)):
        step = se2.relative(poses[kept[-1]], poses[index])
        too_far = math.hypot(step[0], step[1]) > distance or abs(step[2]) > angle
        if too_far and index - 1 > kept[-1]:
            kept.append(index - 1)
    chosen = np.array(kept)
    return Dataset(f'{dataset.name}-steps', [dataset.scans[i] for i in kept],
                   dataset.odometry, Trajectory(dataset.reference.stamps_ns[chosen],
                                                poses[chosen]))
