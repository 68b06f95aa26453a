"""``laser_odom_simulate``: write a simulated ROS 2 bag with scans, ground truth and odometry.

The bag holds ``/scan`` (sensor_msgs/LaserScan), ``/ground_truth`` (nav_msgs/Odometry,
the true base pose at every scan, frame ``map``) and ``/odom`` (noisy wheel odometry,
frame ``odom``); the ground truth is also written as a TUM file beside the bag.
``--sensor`` picks a lidar preset (:mod:`laser_odom.core.simulation.sensors`); the
laser options given on the command line override the preset's figures.
Everything is deterministic for a given ``--seed``.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
import sys
from typing import Sequence

import numpy as np

from laser_odom.core.scan.laser_scan import LaserMounting
from laser_odom.core.simulation import (
    DEFAULT_MOTION, DEFAULT_SENSOR, DEFAULT_WORLD, LaserModel, MOTIONS, ODOMETRY_RATE,
    OdometryNoise, sensor_model, sensor_names, SENSORS, simulate, STAMP_AT, world_names)
from laser_odom.io.bag_writer import STORAGES, write_bag
from laser_odom.io.errors import BagWriteError, OutputExistsError
from laser_odom.io.tum import write_tum
from laser_odom.tools.arguments import number_in

PROG = 'laser_odom_simulate'


LASER_OPTIONS = {'beams': 'beams', 'fov': 'fov', 'max_range': 'max_range',
                 'min_range': 'min_range', 'noise': 'noise_sigma', 'dropout': 'dropout',
                 'rate': 'rate'}
"""Command-line laser options (``None`` unless given) and the model fields they set."""


def _sensor_help() -> str:
    """Return the ``--sensor`` help: every preset with its figures."""
    presets = '; '.join(f'{name}: {preset.description}' for name, preset in SENSORS.items())
    return (f'lidar preset (default: {DEFAULT_SENSOR}). {presets}. All but ideal sweep their '
            'beams over one revolution per scan while the robot moves; --beams, --fov, '
            '--max-range, --min-range, --noise, --dropout and --rate override the preset')


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    defaults = LaserModel()
    preset = ' (default: from --sensor; ideal: {})'
    p = argparse.ArgumentParser(
        prog=PROG, description='Simulate a robot driving a 2D world and write a ROS 2 bag '
        'with /scan, /ground_truth and /odom, plus the ground truth as a TUM file.')
    p.add_argument('out', metavar='OUT', type=Path, help='bag directory to create')
    p.add_argument('--world', default=DEFAULT_WORLD, choices=world_names(),
                   help='world to drive: office, corridor, cluttered, featureless_corridor, '
                   'campus (outdoor, 150 x 100 m, buildings tens of metres apart, trees, '
                   'open ground; a 220 m loop) or hall (a 60 x 30 m convention hall, '
                   f'sparse pillars and booths; a 120 m loop) (default: {DEFAULT_WORLD})')
    p.add_argument('--motion', default=DEFAULT_MOTION, choices=MOTIONS,
                   help='how the robot drives: gentle (0.45 m/s), spin (stops to turn in '
                   'place at up to 3 rad/s), aggressive (up to 1.5 m/s, fast '
                   'accelerations) or fast (1 m/s, corners at up to 1.5 rad/s; e.g. '
                   f'--sensor rplidar_a1 --rate 5) (default: {DEFAULT_MOTION})')
    p.add_argument('--drop', type=number_in(float, 0.0, 0.99), default=0.0, metavar='P',
                   help='probability that a scan is dropped (never the first; its ground '
                   'truth goes too) (default: 0)')
    p.add_argument('--duration', type=number_in(float, 0.0, 1e6, True), default=60.0,
                   metavar='S', help='simulated time [s] (default: 60)')
    p.add_argument('--sensor', default=DEFAULT_SENSOR, choices=sensor_names(),
                   help=_sensor_help())
    p.add_argument('--reverse-sweep', action='store_true',
                   help='the lidar sweeps clockwise, as some drivers publish: negative '
                   'angle_increment, first beam at the highest angle')
    p.add_argument('--stamp-at', choices=STAMP_AT, default='first',
                   help='which beam the scan stamp belongs to: first (the ROS drivers) or '
                   'last; the ground truth is the pose at the stamp; no effect with the '
                   'instantaneous ideal sensor (default: first)')
    p.add_argument('--beams', type=number_in(int, 2, 100000, what='integer'), default=None,
                   metavar='N', help='beams per scan' + preset.format(defaults.beams))
    p.add_argument('--fov', type=number_in(float, 0.0, 360.0, True), default=None,
                   metavar='DEG', help='field of view [deg]' + preset.format(360))
    p.add_argument('--max-range', type=number_in(float, 0.0, 1e4, True), default=None,
                   metavar='M', help='max range [m]' + preset.format(f'{defaults.max_range:g}'))
    p.add_argument('--min-range', type=number_in(float, 0.0, 1e4), default=None,
                   metavar='M', help='min range [m]' + preset.format(defaults.min_range))
    p.add_argument('--noise', type=number_in(float, 0.0, 10.0), default=None,
                   metavar='SIGMA', help='range noise std. dev. [m]'
                   + preset.format(defaults.noise_sigma))
    p.add_argument('--dropout', type=number_in(float, 0.0, 1.0), default=None,
                   metavar='P', help='probability of a NaN reading'
                   + preset.format(f'{defaults.dropout:g}'))
    p.add_argument('--rate', type=number_in(float, 0.0, 1000.0, True), default=None,
                   metavar='HZ', help='scan rate [Hz]' + preset.format(f'{defaults.rate:g}'))
    p.add_argument('--odom-rate', type=number_in(float, 0.0, 10000.0, True),
                   default=ODOMETRY_RATE, metavar='HZ', help='wheel odometry rate [Hz] '
                   '(default: 50)')
    p.add_argument('--odom-noise', type=number_in(float, 0.0, 100.0), default=1.0,
                   metavar='FACTOR', help='scale of the wheel odometry errors; 0 gives '
                   'perfect odometry (default: 1)')
    p.add_argument('--seed', type=number_in(int, 0, 2 ** 63 - 1, what='integer'), default=0,
                   metavar='N', help='random seed (default: 0)')
    p.add_argument('--storage', choices=list(STORAGES), default='sqlite3',
                   help='bag storage (default: sqlite3)')
    p.add_argument('--laser-x', type=number_in(float, -10.0, 10.0), default=0.0, metavar='M',
                   help='laser position on the base, x [m]')
    p.add_argument('--laser-y', type=number_in(float, -10.0, 10.0), default=0.0, metavar='M',
                   help='laser position on the base, y [m]')
    p.add_argument('--laser-yaw', type=number_in(float, -math.pi, math.pi), default=0.0,
                   metavar='RAD', help='laser yaw on the base [rad]')
    p.add_argument('--laser-upside-down', action='store_true',
                   help='laser mounted upside down (mirrored scan)')
    p.add_argument('--tum', type=Path, default=None, metavar='PATH',
                   help='ground-truth TUM file (default: OUT.tum)')
    return p


def _fail(message: str) -> int:
    """Print a one-line error and return the input-error exit code 2."""
    print(f'{PROG}: error: {message}', file=sys.stderr)
    return 2


def laser_from_args(args: argparse.Namespace) -> LaserModel:
    """Return the ``--sensor`` preset with the laser options given on the command line."""
    overrides = {field: getattr(args, option) for option, field in LASER_OPTIONS.items()
                 if getattr(args, option) is not None}
    if 'fov' in overrides:
        overrides['fov'] = math.radians(overrides['fov'])
    return sensor_model(args.sensor, reverse=args.reverse_sweep, stamp_at=args.stamp_at,
                        **overrides)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the simulator; return the exit code (2 for usage and input errors)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        laser = laser_from_args(args)
    except ValueError as error:
        if 'min_range' in str(error):
            parser.error('--min-range must be smaller than --max-range')
        parser.error(str(error))
    out: Path = args.out
    if out.exists() or out.is_symlink():
        return _fail(f'{out} exists already; not overwriting it')
    tum: Path = args.tum if args.tum is not None else out.with_name(out.name + '.tum')
    if tum.exists() or tum.is_symlink():
        return _fail(f'{tum} exists already; not overwriting it')
    mounting = LaserMounting(args.laser_x, args.laser_y, args.laser_yaw, args.laser_upside_down)
    data = simulate(args.world, args.duration, laser, args.seed, mounting,
                    OdometryNoise().scaled(args.odom_noise), args.odom_rate,
                    motion=args.motion, drop=args.drop)
    try:
        write_bag(out, data.scans, odometry={'/ground_truth': data.reference,
                                             '/odom': data.odometry},
                  storage=args.storage, frame_ids={'/ground_truth': 'map'})
        write_tum(tum, data.reference, overwrite=False)
    except (OutputExistsError, BagWriteError, OSError) as error:
        return _fail(str(error))
    driven = float(np.hypot(*np.diff(data.reference.poses[:, :2], axis=0).T).sum())
    laser_on_base = '' if mounting.is_identity else (
        f', laser at x={mounting.x:g} y={mounting.y:g} yaw={mounting.yaw:g}'
        + (' upside down' if mounting.upside_down else ''))
    motion = '' if args.motion == DEFAULT_MOTION else f', {args.motion} motion'
    dropped = f', {args.drop:.0%} dropped' if args.drop > 0.0 else ''
    sensor = '' if args.sensor == DEFAULT_SENSOR else f'{args.sensor}, '
    clockwise = 'clockwise ' if laser.reverse else ''
    sweep = (f', {laser.sweep_time * 1e3:.4g} ms {clockwise}sweep' if laser.sweep
             else f', {clockwise}instantaneous' if laser.reverse else '') + (
        ' stamped at the last beam' if laser.sweep and laser.stamp_at == 'last' else '')
    print(f'wrote {out}: {len(data.scans)} scans ({args.world}{motion}, {args.duration:g} s, '
          f'{sensor}{laser.beams} beams{sweep}{laser_on_base}{dropped}, '
          f'{driven:.1f} m driven), '
          f'{len(data.odometry)} odometry, ground truth {tum}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
