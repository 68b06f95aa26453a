"""``laser_odom_bench``: score every matcher for accuracy and speed in one table.

Rows are dataset x matcher x prior x deskew setting x reference (``scan`` or
``local_map``). Datasets are the simulated ones
(generated here) plus every real dataset found under ``--data-dir``; ``--grid deskew``
adds (or, without ``--datasets``, runs only) the simulated rotating lidars driven
``gentle``, ``spin``, ``aggressive`` and turning, and ``--grid worlds`` the outdoor
campus and the convention hall driven slow and fast at 5 Hz; both are left out by default.
Timing is taken inside this process around the whole per-scan work of the pipeline
(conversion, tree build, matching), after a warm-up.

``--bag PATH`` (repeatable) adds the user's own bags as datasets, named after the bag's
directory or file: their scans, their ``/odom`` wheel odometry (the ``odom`` prior and
the ``wheel_odometry`` row) and a reference - the i-th ``--reference REF.tum``, or else
the bag's ``/ground_truth`` Odometry topic. Without ``--datasets`` or ``--grid`` only
the bags run. A bag without any reference is timed only: its accuracy columns and
``failed`` are ``n/a`` (NaN and null in ``--json``), and it has no wheel odometry row.

Every scored row also holds the consistency of its published covariance (mean NEES over
windows of 1, 10 and 100 steps and of the integrated pose, with the reference's own
noise accounted for on real logs: ``--reference-noise-m``, ``--reference-noise-deg``);
``--nees`` prints them as a second table, ``--json`` always has them.

A progress bar is drawn on stderr only when stderr is a terminal (never into a pipe or
a log file); ``--quiet`` leaves it out and silences warnings too (see
:func:`warnings_silenced`), while errors are still printed.
"""

from __future__ import annotations

import argparse
from functools import lru_cache
import json
import logging
import math
from pathlib import Path
import sys
from typing import Any, Callable, Mapping, Sequence

from laser_odom.core.datasets import (
    as_received, DatasetError, discover_datasets, KNOWN_DATASETS, load_dataset,
    RANGE_NOISE_M, SUBSAMPLED_DATASETS, subsampled_datasets)
from laser_odom.core.evaluation.benchmark import (
    BENCH_PRIORS, BenchRow, DEFAULT_BENCH_PRIORS, DESKEW_MODES, GRIDS, REAL_REFERENCE_NOISE,
    REFERENCE_MODES, SIMULATED)
from laser_odom.core.evaluation.consistency import NO_REFERENCE_NOISE, ReferenceNoise
from laser_odom.core.evaluation.search_timing import search_timing, SearchTimingRow
from laser_odom.core.evaluation.spread import spread_rows
from laser_odom.core.matchers import matcher_names
from laser_odom.core.parameters import ParameterError
from laser_odom.core.trajectory import Dataset
from laser_odom.io.bag_dataset import (
    BAG_GROUND_TRUTH, bag_loaders, BAG_ODOMETRY, NO_REFERENCE)
from laser_odom.io.bag_reader import BagError
from laser_odom.io.params_file import ParamsFileError, read_params_files
from laser_odom.io.text_output import reader_may_leave, write_text_atomically
from laser_odom.tools.bench_runs import dataset_copies, run_tasks, simulated_here
from laser_odom.tools.bench_table import (
    format_nees_table, format_search_table, format_spread_table, format_table, machine_line,
    provenance)
from laser_odom.tools.quiet import warnings_silenced

LOGGER = logging.getLogger('laser_odom.tools.bench')
"""Where the benchmark's own warnings go (stderr; ``--quiet`` silences them)."""

DEFAULT_DATA_DIR = Path(__file__).resolve().parents[2].parent / 'shared' / 'data'
"""``../shared/data`` beside a source checkout, the project's real logs."""


def progress_wanted(args: argparse.Namespace) -> bool:
    """Tell whether to draw progress bars: not asked away, and stderr is a terminal."""
    return not (args.no_progress or args.quiet) and sys.stderr.isatty()


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """Parse the command line."""
    parser = argparse.ArgumentParser(
        prog='laser_odom_bench', description='Score matchers on simulated and real datasets, '
        'matching each scan against the previous scan and/or a local map of the recent '
        'scans (--reference-modes scan,local_map).')
    parser.add_argument('--matchers', default=','.join(matcher_names()),
                        help='comma-separated matcher names (default: all)')
    parser.add_argument('--datasets', default=None,
                        help='comma-separated dataset names (default: all simulated and '
                             'every real dataset found, except the --grid datasets)')
    parser.add_argument('--grid', default=None, metavar='LIST',
                        help='comma-separated groups of datasets to add, left out by '
                             'default (without --datasets: run only them). The group '
                             'deskew is the simulated rotating lidars (lds01, rplidar_a1, '
                             'ld06, ust10lx, tim571) in the office driven gentle, spin and '
                             'aggressive, sim-SENSOR-MOTION (60 s; ust10lx 20 s), and '
                             'sim-lds01-turning, sim-rplidar_a1-turning (0.3 m/s, '
                             '1.5 rad/s, 20 s). The group worlds is the campus (tim571 '
                             'figures) and the hall (rplidar_a1) at 5 Hz, slow (gentle) and '
                             'fast (1 m/s, 1.5 rad/s), seeds 1-3, sim-WORLD-SPEED-sSEED '
                             '(120 s; the slow campus 240 s)')
    parser.add_argument('--priors', default=','.join(DEFAULT_BENCH_PRIORS),
                        help='comma-separated priors: none, constant_velocity, odom '
                             '(default: all three)')
    parser.add_argument('--deskew', default=None, metavar='LIST',
                        help='comma-separated deskew values (auto, on, off): every row runs '
                             'with each, shown in the deskew column (default: auto, or the '
                             "--params-file's deskew)")
    parser.add_argument('--reference-modes', default=None, metavar='LIST',
                        help='comma-separated reference values (scan, local_map): every '
                             'row matches against each, shown in the reference column '
                             "(default: scan, or the --params-file's reference)")
    parser.add_argument('--bag', action='append', default=[], metavar='PATH',
                        help='a ROS 1 or ROS 2 bag of your own as a dataset, named after '
                             'its directory or file (repeatable): its LaserScan topic, '
                             f'{BAG_ODOMETRY} as wheel odometry if present. Without '
                             '--datasets or --grid only the bags run')
    parser.add_argument('--reference', action='append', default=[], metavar='REF.tum',
                        help='reference TUM file of the i-th --bag (repeatable; '
                             f"{NO_REFERENCE!r}: no file). Default: the bag's "
                             f'{BAG_GROUND_TRUTH} Odometry topic; without either the bag '
                             'is timed only (accuracy n/a)')
    parser.add_argument('--scan-topic', default=None, metavar='TOPIC',
                        help='LaserScan topic of every --bag (default: the only one)')
    parser.add_argument('--data-dir', type=Path, default=DEFAULT_DATA_DIR,
                        help='folder holding the real logs (default: ../shared/data)')
    parser.add_argument('--params-file', type=Path, default=None, metavar='YAML',
                        help="the node's parameter file: every row runs with its settings "
                             '(except matcher and prior, which each row sets, and deskew '
                             'when --deskew is given)')
    parser.add_argument('--perturb', type=int, default=0, metavar='N',
                        help='run N copies of every dataset, each with Gaussian noise of '
                             '--range-noise on every range (seeds 1..N), and print the '
                             'median [worst] of each figure over the copies (default 0: '
                             'the dataset once, as received)')
    parser.add_argument('--range-noise', type=float, default=RANGE_NOISE_M, metavar='M',
                        help=f'range noise of a --perturb copy [m] (default {RANGE_NOISE_M:g})')
    parser.add_argument('--jobs', type=int, default=1, metavar='N',
                        help='run the copies of the datasets in N processes side by side '
                             '(default 1; the figures are the same, the timings are taken '
                             'with the processes sharing the machine)')
    parser.add_argument('--json', type=Path, default=None, help='also write rows as JSON')
    parser.add_argument('--no-progress', action='store_true',
                        help='no progress bar (it is drawn on stderr only when stderr is '
                             'a terminal)')
    parser.add_argument('--quiet', action='store_true',
                        help='no progress bar and no warnings; errors are still printed')
    parser.add_argument('--no-search-table', action='store_true',
                        help='leave out the table that times the global search alone')
    parser.add_argument('--nees', action='store_true',
                        help='also print the consistency table: mean NEES of the relative '
                             'pose over windows of 1, 10 and 100 steps and of the '
                             'integrated pose, about 3 when the published covariance is '
                             'honest (always in --json)')
    parser.add_argument('--reference-noise-m', type=float,
                        default=REAL_REFERENCE_NOISE.translation, metavar='M',
                        help='noise of each reference pose in x and in y [m] that the NEES '
                             'accounts for, on every dataset not simulated here (real '
                             'logs, --bag references); simulated datasets are scored '
                             'against the truth, with none (default '
                             f'{REAL_REFERENCE_NOISE.translation:g})')
    parser.add_argument('--reference-noise-deg', type=float,
                        default=math.degrees(REAL_REFERENCE_NOISE.rotation), metavar='DEG',
                        help='the same in heading [deg] (default '
                             f'{math.degrees(REAL_REFERENCE_NOISE.rotation):g})')
    live = parser.add_argument_group(
        'live', 'stream simulated scans over DDS to a laser_odom_node per matcher')
    live.add_argument('--live', action='store_true',
                      help='run the live benchmark instead of the offline table')
    live.add_argument('--rate', type=float, default=40.0, help='scan rate [Hz] (default 40)')
    live.add_argument('--beams', type=int, default=1081, help='beams per scan (default 1081)')
    live.add_argument('--duration', type=float, default=60.0,
                      help='seconds of scans per matcher (default 60)')
    return parser.parse_args(argv)


def _split(text: str, valid: Sequence[str], what: str) -> list[str]:
    """Split a comma list and check every item is valid."""
    items = [item.strip() for item in text.split(',') if item.strip()]
    bad = [item for item in items if item not in valid]
    if bad or not items:
        raise ValueError(f'unknown {what}: {", ".join(bad) or "(none given)"}; '
                         f'valid: {", ".join(valid)}')
    return items


def dataset_loaders(data_dir: Path) -> dict[str, Callable[[], Dataset]]:
    """Return name -> loader for every simulated (grids too) and every real dataset found.

    Subsampled datasets (``fr079/5``) share one load of their base log.
    """
    specs = {**SIMULATED, **{name: spec for grid in GRIDS.values()
                             for name, spec in grid.items()}}
    loaders: dict[str, Callable[[], Dataset]] = {
        name: (lambda name=name, spec=spec: spec.generate(name))
        for name, spec in specs.items()}
    if data_dir.is_dir():
        found = discover_datasets(data_dir)
        for name, path in found.items():
            loaders[name] = lru_cache(maxsize=1)(
                lambda path=path, name=name: load_dataset(path, name=name))
        for name, spec in subsampled_datasets(found).items():
            loaders[name] = (lambda name=name, base=loaders[spec.base], spec=spec:
                             spec.derive(base(), name))
    return loaders


def dataset_names(args: argparse.Namespace, loaders: Mapping[str, object],
                  bags: Sequence[str] = ()) -> list[str]:
    """Return the datasets to run: ``--datasets`` (default: all but grids), ``--grid``, bags.

    ``bags`` are the names of the ``--bag`` datasets: with them, and neither
    ``--datasets`` nor ``--grid``, only they run.
    """
    grids = _split(args.grid, list(GRIDS), 'grid') if args.grid else []
    if args.datasets:
        absent = [name for name in args.datasets.split(',') if name.strip() not in loaders
                  and name.strip() in {*KNOWN_DATASETS, *SUBSAMPLED_DATASETS}]
        if absent:
            folders = sorted({path.split('/')[0] + '/' for path in KNOWN_DATASETS.values()})
            raise ValueError(f'{", ".join(absent)}: a real log, not found under '
                             f'{args.data_dir} (pass --data-dir DIR, the folder that holds '
                             f'{", ".join(folders)})')
        names = _split(args.datasets, list(loaders), 'dataset')
    elif grids or bags:
        names = []
    else:
        in_grids = {name for grid in GRIDS.values() for name in grid}
        names = [name for name in loaders if name not in in_grids]
    for grid in grids:
        names += _split(','.join(GRIDS[grid]), list(loaders), 'dataset')
    return list(dict.fromkeys(names + list(bags)))


def reference_noise(args: argparse.Namespace, name: str) -> ReferenceNoise:
    """Return the noise of the dataset's reference poses: none when it is simulated here.

    Anything else (a real log's SLAM-corrected poses, a bag's reference) takes
    ``--reference-noise-m`` and ``--reference-noise-deg``.
    """
    if simulated_here(name):
        return NO_REFERENCE_NOISE
    return ReferenceNoise.degrees(args.reference_noise_m, args.reference_noise_deg)


def run(args: argparse.Namespace) -> tuple[list[BenchRow], list[SearchTimingRow]]:
    """Run every selected dataset x matcher x prior x deskew; return rows, search timings."""
    for option, value in (('--reference-noise-m', args.reference_noise_m),
                          ('--reference-noise-deg', args.reference_noise_deg)):
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f'{option} must be a finite number >= 0, got {value:g}')
    loaders = dataset_loaders(args.data_dir)
    values: dict[str, Any] = {}
    if args.params_file is not None:
        checked = read_params_files([args.params_file], require_section=True)
        values = checked.values
        for warning in checked.warnings:
            LOGGER.warning('laser_odom_bench: warning: %s', warning)
    matchers = _split(args.matchers, matcher_names(), 'matcher')
    priors = _split(args.priors, list(BENCH_PRIORS), 'prior')
    deskews: list[str | None] = (
        list(dict.fromkeys(_split(args.deskew, DESKEW_MODES, 'deskew value')))
        if args.deskew is not None else [None])
    references: list[str | None] = (
        list(dict.fromkeys(_split(args.reference_modes, REFERENCE_MODES, 'reference value')))
        if args.reference_modes is not None else [None])
    bags = bag_loaders(args.bag, args.reference, loaders, args.scan_topic)
    loaders.update(bags)
    names = dataset_names(args, loaders, list(bags))
    rows: list[BenchRow] = []
    searches: list[SearchTimingRow] = []
    progress = progress_wanted(args)
    if args.perturb < 0 or not (math.isfinite(args.range_noise) and args.range_noise >= 0.0):
        raise ValueError('--perturb must be >= 0 and --range-noise a finite number >= 0')
    if args.jobs < 1:
        raise ValueError(f'--jobs must be at least 1, got {args.jobs}')
    tasks: list[tuple] = []
    for name in names:
        loaded = loaders[name]()
        noise = reference_noise(args, name)
        for copy, dataset in dataset_copies(loaded, args.perturb, args.range_noise):
            tasks.append((dataset, copy, matchers, priors, deskews, references, values, noise,
                          progress and args.jobs == 1))
        if not args.no_search_table:
            searches.append(search_timing(as_received(loaded)))
    for task_rows in run_tasks(tasks, args.jobs):
        rows += task_rows
    return rows, searches


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark and print its table; 2 on a usage or data error."""
    args = parse_args(argv)
    with reader_may_leave(), warnings_silenced(args.quiet):
        return main_live(args) if args.live else main_offline(args)


def main_offline(args: argparse.Namespace) -> int:
    """Run the offline benchmark and print its tables."""
    try:
        rows, searches = run(args)
    except (DatasetError, ParamsFileError, ParameterError, ValueError, BagError) as err:
        print(f'laser_odom_bench: error: {err}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print('laser_odom_bench: interrupted', file=sys.stderr)
        return 130
    spreads = spread_rows(rows)
    if args.json is not None:  # first: a reader leaving the printed table loses nothing
        payload = {**provenance(), 'rows': [row.as_dict() for row in rows],
                   'spread': [row.as_dict() for row in spreads],
                   'search': [row.as_dict() for row in searches]}
        write_text_atomically(args.json, json.dumps(payload, indent=2) + '\n')
    print(machine_line())
    print(format_table(rows))
    if args.perturb:
        print(format_spread_table(spreads))
    if args.nees:
        print(format_nees_table(rows))
    if searches:
        print(format_search_table(searches))
    return 0


def main_live(args: argparse.Namespace) -> int:
    """Run the live (DDS) benchmark and print its table."""
    try:
        matchers = _split(args.matchers, matcher_names(), 'matcher')
        if args.rate <= 0 or args.beams < 2 or args.duration <= 0:
            raise ValueError('--rate and --duration must be positive, --beams at least 2')
        values: dict[str, Any] = {}
        if args.params_file is not None:  # the node reads it too; checked here first
            values = read_params_files([args.params_file], require_section=True).values
        references = (_split(args.reference_modes, REFERENCE_MODES, 'reference value')
                      if args.reference_modes is not None else [values.get('reference',
                                                                           'scan')])
        from laser_odom.tools.bench_live import format_live, run_live
        rows = run_live(matchers, args.beams, args.rate, args.duration,
                        references=references, params_file=args.params_file)
    except (ValueError, RuntimeError) as err:  # ParamsFileError is a ValueError
        print(f'laser_odom_bench: error: {err}', file=sys.stderr)
        return 2
    if args.json is not None:
        write_text_atomically(args.json, json.dumps(
            {**provenance(), 'live': [vars(row) for row in rows]},
            indent=2) + '\n')
    print(machine_line(live=True))
    print(format_live(rows, args.beams, args.rate, args.duration))
    return 0


if __name__ == '__main__':
    sys.exit(main())
