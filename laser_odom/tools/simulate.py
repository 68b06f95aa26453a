"""``laser_odom_simulate``: write a simulated ROS 2 bag with scans, ground truth and odometry.

The bag holds ``/scan`` (sensor_msgs/LaserScan), ``/ground_truth`` (nav_msgs/Odometry,
the true base pose at every scan, frame ``map``) and ``/odom`` (noisy wheel odometry,
frame ``odom``); the ground truth is also written as a TUM file beside the bag.
Everything is deterministic for a given ``--seed``.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
import sys
from typing import Callable, Sequence

import numpy as np

from laser_odom.core.scan import LaserMounting
from laser_odom.core.simulation import (
    DEFAULT_MOTION, DEFAULT_WORLD, LaserModel, MOTIONS, ODOMETRY_RATE, OdometryNoise, simulate,
    world_names)
from laser_odom.io.bag_writer import STORAGES, write_bag
from laser_odom.io.errors import BagWriteError, OutputExistsError
from laser_odom.io.tum import write_tum

PROG = 'laser_odom_simulate'


def _number(kind: type, low: float, high: float, low_open: bool = False,
            what: str = 'value') -> Callable[[str], float]:
    """Return an argparse type that parses ``kind`` and checks its range."""
    def parse(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f'{text!r} is not a valid {what}') from None
        if not math.isfinite(value) or value < low or value > high or (
                low_open and value == low):
            bracket = '(' if low_open else '['
            raise argparse.ArgumentTypeError(
                f'{text} is outside {bracket}{low:g}, {high:g}]')
        return value
    return parse


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    defaults = LaserModel()
    p = argparse.ArgumentParser(
        prog=PROG, description='Simulate a robot driving a 2D world and write a ROS 2 bag '
        'with /scan, /ground_truth and /odom, plus the ground truth as a TUM file.')
    p.add_argument('out', metavar='OUT', type=Path, help='bag directory to create')
    p.add_argument('--world', default=DEFAULT_WORLD, choices=world_names(),
                   help=f'world to drive (default: {DEFAULT_WORLD})')
    p.add_argument('--motion', default=DEFAULT_MOTION, choices=MOTIONS,
                   help='how the robot drives: gentle (0.45 m/s), spin (stops to turn in '
                   'place at up to 3 rad/s) or aggressive (up to 1.5 m/s, fast '
                   f'accelerations) (default: {DEFAULT_MOTION})')
    p.add_argument('--drop', type=_number(float, 0.0, 0.99), default=0.0, metavar='P',
                   help='probability that a scan is dropped (never the first; its ground '
                   'truth goes too) (default: 0)')
    p.add_argument('--duration', type=_number(float, 0.0, 1e6, True), default=60.0,
                   metavar='S', help='simulated time [s] (default: 60)')
    p.add_argument('--beams', type=_number(int, 2, 100000, what='integer'),
                   default=defaults.beams, metavar='N', help='beams per scan (default: 360)')
    p.add_argument('--fov', type=_number(float, 0.0, 360.0, True), default=360.0,
                   metavar='DEG', help='field of view [deg] (default: 360)')
    p.add_argument('--max-range', type=_number(float, 0.0, 1e4, True),
                   default=defaults.max_range, metavar='M', help='max range [m] (default: 20)')
    p.add_argument('--min-range', type=_number(float, 0.0, 1e4), default=defaults.min_range,
                   metavar='M', help='min range [m] (default: 0.05)')
    p.add_argument('--noise', type=_number(float, 0.0, 10.0), default=defaults.noise_sigma,
                   metavar='SIGMA', help='range noise std. dev. [m] (default: 0.01)')
    p.add_argument('--dropout', type=_number(float, 0.0, 1.0), default=defaults.dropout,
                   metavar='P', help='probability of a NaN reading (default: 0)')
    p.add_argument('--rate', type=_number(float, 0.0, 1000.0, True), default=defaults.rate,
                   metavar='HZ', help='scan rate [Hz] (default: 10)')
    p.add_argument('--odom-rate', type=_number(float, 0.0, 10000.0, True),
                   default=ODOMETRY_RATE, metavar='HZ', help='wheel odometry rate [Hz] '
                   '(default: 50)')
    p.add_argument('--odom-noise', type=_number(float, 0.0, 100.0), default=1.0,
                   metavar='FACTOR', help='scale of the wheel odometry errors; 0 gives '
                   'perfect odometry (default: 1)')
    p.add_argument('--seed', type=_number(int, 0, 2 ** 63 - 1, what='integer'), default=0,
                   metavar='N', help='random seed (default: 0)')
    p.add_argument('--storage', choices=list(STORAGES), default='sqlite3',
                   help='bag storage (default: sqlite3)')
    p.add_argument('--laser-x', type=_number(float, -10.0, 10.0), default=0.0, metavar='M',
                   help='laser position on the base, x [m]')
    p.add_argument('--laser-y', type=_number(float, -10.0, 10.0), default=0.0, metavar='M',
                   help='laser position on the base, y [m]')
    p.add_argument('--laser-yaw', type=_number(float, -math.pi, math.pi), default=0.0,
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


def main(argv: Sequence[str] | None = None) -> int:
    """Run the simulator; return the exit code (2 for usage and input errors)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.min_range >= args.max_range:
        parser.error('--min-range must be smaller than --max-range')
    out: Path = args.out
    if out.exists() or out.is_symlink():
        return _fail(f'{out} exists already; not overwriting it')
    tum: Path = args.tum if args.tum is not None else out.with_name(out.name + '.tum')
    if tum.exists() or tum.is_symlink():
        return _fail(f'{tum} exists already; not overwriting it')
    laser = LaserModel(beams=args.beams, fov=math.radians(args.fov), max_range=args.max_range,
                       min_range=args.min_range, noise_sigma=args.noise, dropout=args.dropout,
                       rate=args.rate)
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
    print(f'wrote {out}: {len(data.scans)} scans ({args.world}{motion}, {args.duration:g} s, '
          f'{args.beams} beams{laser_on_base}{dropped}, {driven:.1f} m driven), '
          f'{len(data.odometry)} odometry, ground truth {tum}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
