"""Soak test: run many simulated scans through the pipeline and watch resident memory.

``python -m laser_odom.tools.soak --scans 100000`` (or ``make soak``) renders scans on
the fly along the simulated path (nothing is accumulated), feeds them through one
pipeline, and prints the resident set size every ``--report-every`` scans. Memory
must not grow with the number of scans: every per-scan structure is either replaced
(the reference scan) or bounded (timing window, event counters).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import Iterator, Sequence

import numpy as np

from laser_odom.core.config import DEFAULT_MATCHER, PipelineConfig
from laser_odom.core.events import EventLog
from laser_odom.core.matchers import matcher_names
from laser_odom.core.pipeline import OdometryPipeline
from laser_odom.core.scan import LaserScan
from laser_odom.core.simulation import EPOCH_NS, get_world, LaserModel, render_scan

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


def main(argv: Sequence[str] | None = None) -> int:
    """Run the soak and print a memory table; exit 1 if memory grew past the limit."""
    parser = argparse.ArgumentParser(prog='laser_odom_soak', description=__doc__.split('\n')[0])
    parser.add_argument('--scans', type=int, default=100_000)
    parser.add_argument('--matcher', default=DEFAULT_MATCHER, choices=matcher_names())
    parser.add_argument('--world', default='office')
    parser.add_argument('--beams', type=int, default=360)
    parser.add_argument('--report-every', type=int, default=10_000)
    parser.add_argument('--limit-mib', type=float, default=20.0,
                        help='allowed growth of resident memory after warm-up [MiB]')
    args = parser.parse_args(argv)
    if args.scans <= WARMUP_SCANS:
        parser.error(f'--scans must be more than the {WARMUP_SCANS} warm-up scans')
    pipeline = OdometryPipeline(PipelineConfig(matcher=args.matcher),
                                events=EventLog(lambda message: None))
    laser = LaserModel(beams=args.beams)
    baseline = None
    started = time.monotonic()
    print(f'# soak: {args.scans} scans, matcher {args.matcher}, world {args.world}, '
          f'{args.beams} beams')
    print(f'{"scans":>8} {"RSS MiB":>9} {"growth":>8} {"elapsed s":>10}')
    for count, scan in enumerate(scan_stream(args.world, args.scans, laser, 0), start=1):
        pipeline.process(scan)
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
          f'(limit {args.limit_mib:.0f} MiB); counters: {counters}')
    return 0 if growth < args.limit_mib else 1


if __name__ == '__main__':
    sys.exit(main())
