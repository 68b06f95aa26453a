"""``laser_odom_convert``: turn a CARMEN log or a scan .mat file into a ROS 2 bag.

The bag holds ``/scan`` (sensor_msgs/LaserScan, frame ``laser``), ``/odom`` (the log's
raw wheel odometry as nav_msgs/Odometry, frame ``odom``) and, when the log has a
reference (a GMapping-corrected log's per-scan poses or a ``reference_keyframes.txt``
join), ``/ground_truth`` (nav_msgs/Odometry, frame ``map``) plus the same reference as a
TUM file, the layout ``laser_odom_simulate`` writes, so replay and benchmark tools read
real and simulated data alike. Loading rules (beam angles, no-return readings, stamp
repair) are those of :mod:`laser_odom.core.datasets`; its warnings (skipped malformed
lines, re-stamped scans) are printed on stderr.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
import sys
from typing import Sequence

from laser_odom.core.datasets import DatasetError, load_dataset
from laser_odom.io.bag_writer import STORAGES, write_bag
from laser_odom.io.errors import BagWriteError, OutputExistsError
from laser_odom.io.tum import write_tum

PROG = 'laser_odom_convert'
DATASET_LOGGER = 'laser_odom.core.datasets'


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    p = argparse.ArgumentParser(
        prog=PROG, description='Convert a CARMEN log (.clf, .log, optionally .gz) or a '
        'scan_intel.mat-style file to a ROS 2 bag with /scan, /odom and, when the log has '
        'a reference, /ground_truth plus a TUM reference file.')
    p.add_argument('input', metavar='INPUT', type=Path, help='log or .mat file to convert')
    p.add_argument('out', metavar='OUT_BAG', type=Path, help='bag directory to create')
    p.add_argument('--storage', choices=list(STORAGES), default='sqlite3',
                   help='bag storage (default: sqlite3)')
    p.add_argument('--tum', type=Path, default=None, metavar='REF.tum',
                   help='reference TUM file (default: OUT_BAG.tum)')
    p.add_argument('--keyframes', type=Path, default=None, metavar='FILE',
                   help='reference_keyframes.txt to join as the reference (default: the '
                   'one beside INPUT, when it indexes this kind of file)')
    p.add_argument('--strict', action='store_true',
                   help='fail on the first malformed line instead of skipping it')
    return p


def _fail(message: str) -> int:
    """Print a one-line error and return the input-error exit code 2."""
    print(f'{PROG}: error: {message}', file=sys.stderr)
    return 2


def _warnings_to_stderr() -> logging.Handler:
    """Route the dataset loaders' warnings to stderr as ``laser_odom_convert: warning:``."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(f'{PROG}: warning: %(message)s'))
    handler.setLevel(logging.WARNING)
    logging.getLogger(DATASET_LOGGER).addHandler(handler)
    return handler


def main(argv: Sequence[str] | None = None) -> int:
    """Convert one dataset file; return the exit code (2 for usage and input errors)."""
    args = build_parser().parse_args(argv)
    out: Path = args.out
    if out.exists() or out.is_symlink():
        return _fail(f'{out} exists already; not overwriting it')
    handler = _warnings_to_stderr()
    try:
        dataset = load_dataset(args.input, keyframes=args.keyframes, strict=args.strict)
    except DatasetError as error:
        return _fail(str(error))
    finally:
        logging.getLogger(DATASET_LOGGER).removeHandler(handler)
    has_reference = len(dataset.reference) > 0
    tum: Path = args.tum if args.tum is not None else out.with_name(out.name + '.tum')
    if has_reference and (tum.exists() or tum.is_symlink()):
        return _fail(f'{tum} exists already; not overwriting it')
    if not has_reference and args.tum is not None:
        print(f'{PROG}: warning: {args.input} has no reference; {tum} not written',
              file=sys.stderr)
    odometry = {}
    if len(dataset.odometry):
        odometry['/odom'] = dataset.odometry
    if has_reference:
        odometry['/ground_truth'] = dataset.reference
    try:
        write_bag(out, dataset.scans, odometry=odometry, storage=args.storage,
                  frame_ids={'/ground_truth': 'map'})
        if has_reference:
            write_tum(tum, dataset.reference, overwrite=False)
    except (OutputExistsError, BagWriteError, OSError) as error:
        return _fail(str(error))
    reference = (f'{len(dataset.reference)} reference poses, reference {tum}'
                 if has_reference else 'no reference')
    print(f'wrote {out}: {len(dataset.scans)} scans of {dataset.name}, '
          f'{len(dataset.odometry)} odometry, {reference}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
