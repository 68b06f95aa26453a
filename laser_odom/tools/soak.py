"""``laser_odom_soak``: run many simulated scans through one pipeline and watch its memory.

``laser_odom_soak --scans 100000`` (or ``python -m laser_odom.tools.soak``, or
``make soak``) renders scans on the fly along the simulated path (nothing is
accumulated), feeds them through one pipeline, and prints the resident set size every
``--report-every`` scans. Memory must not grow with the number of scans: every per-scan
structure is either replaced (the reference scan) or bounded (timing window, event
counters). Exit codes: 0 the growth after the warm-up stayed under ``--limit-mib``,
1 it did not, 2 a bad argument (one line on stderr).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import Callable, Iterator, NoReturn, Sequence

import numpy as np

from laser_odom.core.configuration.pipeline import DEFAULT_MATCHER, PipelineConfig, REFERENCES
from laser_odom.core.events import EventLog
from laser_odom.core.matchers import matcher_names
from laser_odom.core.pipeline.odometry import OdometryPipeline
from laser_odom.core.scan.laser_scan import LaserScan
from laser_odom.core.simulation import (
    EPOCH_NS, get_world, LaserModel, render_scan, world_names)
from laser_odom.tools.arguments import number_in

PROG = 'laser_odom_soak'

LAP_SCANS = 3000
"""Scans per cycle of precomputed poses (5 minutes at 10 Hz)."""

WARMUP_SCANS = 1000
"""Scans run before the baseline memory reading (imports, caches, allocator pools)."""


def resident_mib() -> float:
    """Return the resident set size of this process [MiB] (Linux /proc)."""
    with open('/proc/self/statm') as statm:
        pages = int(statm.read().split()[1])
    return pages * os.sysconf('SC_PAGE_SIZE') / 2 ** 20


def scan_stream(world: str, count: int, laser: LaserModel, seed: int,
                lap_scans: int = LAP_SCANS) -> Iterator[LaserScan]:
    """Yield ``count`` scans, rendered one at a time along a precomputed stretch of path.

    The poses of ``lap_scans`` scans are computed once and cycled with ever-increasing
    stamps, so the generator itself holds constant memory (the path's own timing
    tables grow with the simulated duration, which would hide what the pipeline does).
    Each wrap-around is one jump of the pose, i.e. one hard match per lap.
    """
    poses = get_world(world).path.poses_at(np.arange(lap_scans) / laser.rate)
    rng = np.random.default_rng(seed)
    period_ns = int(round(1e9 / laser.rate))
    for index in range(count):
        yield render_scan(world, poses[index % lap_scans], laser, rng,
                          EPOCH_NS + index * period_ns)


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (no usage block)."""

    def error(self, message: str) -> NoReturn:
        """Say what is wrong in one line on stderr and exit with status 2."""
        self.exit(2, f'{self.prog}: error: {message} (see --help)\n')


def _scan_count(text: str) -> int:
    """Parse ``--scans``: an integer above the warm-up, which the baseline follows."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r} is not an integer') from None
    if value <= WARMUP_SCANS:
        raise argparse.ArgumentTypeError(
            f'{value} is too few: the memory baseline is read after {WARMUP_SCANS} warm-up '
            f'scans, so give more than {WARMUP_SCANS}')
    return value


def _integer(low: int, high: int) -> Callable[[str], float]:
    """Return an argparse type for an integer in [low, high]."""
    return number_in(int, low, high, what='integer')


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    p = _Parser(
        prog=PROG, description='Run many simulated scans through one odometry pipeline and '
        'print its resident memory as it goes; exit 1 if memory grew by more than '
        '--limit-mib after the warm-up, 2 on a bad argument.')
    p.add_argument('--scans', type=_scan_count, default=100_000, metavar='N',
                   help=f'scans to run, more than the {WARMUP_SCANS} warm-up scans '
                   '(default: 100000)')
    p.add_argument('--matcher', default=DEFAULT_MATCHER, choices=matcher_names(),
                   help=f'scan matcher (default: {DEFAULT_MATCHER})')
    p.add_argument('--reference', default='scan', choices=REFERENCES,
                   help='what each scan is matched against: the previous scan or the local '
                   'map (default: scan)')
    p.add_argument('--world', default='office', choices=world_names(),
                   help='simulated world the scans are rendered in (default: office)')
    p.add_argument('--beams', type=_integer(2, 100_000), default=360, metavar='N',
                   help='beams per scan (default: 360)')
    p.add_argument('--report-every', type=_integer(1, 10 ** 12), default=10_000, metavar='N',
                   help='print a memory line every N scans (default: 10000)')
    p.add_argument('--limit-mib', type=number_in(float, 0.0, 1e6, True), default=20.0,
                   metavar='MIB', help='allowed growth of resident memory after the warm-up '
                   '[MiB]; more exits 1 (default: 20)')
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the soak and print a memory table; return the exit code (see the module)."""
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as stop:  # --help (0) or a bad argument (2, said in one line)
        return stop.code if isinstance(stop.code, int) else 2
    try:
        return soak(args)
    except KeyboardInterrupt:
        print(f'{PROG}: interrupted', file=sys.stderr)
        return 130


def soak(args: argparse.Namespace) -> int:
    """Run the soak described by parsed arguments; return 0, or 1 if memory grew."""
    config = PipelineConfig(matcher=args.matcher)
    config.local_map.reference = args.reference
    pipeline = OdometryPipeline(config, events=EventLog(lambda message: None))
    laser = LaserModel(beams=args.beams)
    baseline = None
    started = time.monotonic()
    print(f'# soak: {args.scans} scans, matcher {args.matcher}, reference {args.reference}, '
          f'world {args.world}, {args.beams} beams')
    print(f'{"scans":>8} {"RSS MiB":>9} {"growth":>8} {"elapsed s":>10}')
    for count, scan in enumerate(scan_stream(args.world, args.scans, laser, 0), start=1):
        pipeline.process(scan)
        pipeline.prepare_next()
        if count == WARMUP_SCANS:
            baseline = resident_mib()
            print(f'{count:>8} {baseline:>9.1f} {0.0:>8.1f} {time.monotonic() - started:>10.0f}')
        elif baseline is not None and (count % args.report_every == 0 or count == args.scans):
            rss = resident_mib()
            print(f'{count:>8} {rss:>9.1f} {rss - baseline:>8.1f} '
                  f'{time.monotonic() - started:>10.0f}', flush=True)
    growth = resident_mib() - baseline
    counters = dict(sorted(pipeline.counters.items()))
    print(f'# resident memory growth after warm-up: {growth:.1f} MiB '
          f'(limit {args.limit_mib:g} MiB); counters: {counters}')
    return 0 if growth < args.limit_mib else 1


if __name__ == '__main__':
    sys.exit(main())
