"""``laser_odom_tune BAG [BAG ...]``: search each matcher's parameters on the user's own bags.

For every matcher (``--matchers``) an Optuna study (:mod:`laser_odom.core.tuning.study`)
searches the space of :mod:`laser_odom.core.tuning.space`, scoring each trial by
running the node's pipeline over the bags (:mod:`laser_odom.core.tuning.objective`):
against a reference when every bag has one (``--reference REF.tum`` per bag, or a
``/ground_truth`` Odometry topic), otherwise reference-free. It prints a table per
matcher (default and best score, trials, wall time) and writes the best matcher's
settings as a params file the node loads as it is (``--output``).

A trial whose laser matches were mostly rejected failed, whatever it scored
(:func:`laser_odom.core.tuning.objective.laser_failure`): it is never recommended, and
the table is followed by why the first failed trial of each matcher failed and by the
best trial's counts per bag (matched, degenerate, rejected), as the replay prints them.

Exit codes: 0 ok, 1 runtime failure (also: every trial failed, nothing written), 2
input error (a bag without scans, a reference that does not overlap its bag, an empty
``--space`` range, a storage that cannot be opened, an unknown matcher, Optuna or
matplotlib missing) - each said in one line.
"""

from __future__ import annotations

import argparse
from functools import partial
import math
from pathlib import Path
import shutil
import sys
import tempfile
from typing import Any, Sequence

from laser_odom.core.configuration.node import parameter_specs
from laser_odom.core.matchers import matcher_names
from laser_odom.core.trajectory import RecordedBag
from laser_odom.core.tuning.objective import describe_counts, OBJECTIVES, REFERENCE_FREE
from laser_odom.core.tuning.space import (
    BASE_PRIORS, matcher_space, read_space_file, SpaceError)
from laser_odom.core.tuning.study import (
    open_storage, plot_data, run_studies, StorageError, StudyMismatchError, StudySummary,
    summarize, table_lines, TuneJob)
from laser_odom.io.bag_dataset import BAG_GROUND_TRUTH, check_overlap, read_bag
from laser_odom.io.bag_reader import BagError
from laser_odom.io.params_file import ParamsFileError, read_params_files
from laser_odom.io.text_output import reader_may_leave, write_text_atomically
from laser_odom.ros.default_params import yaml_value
from laser_odom.tools.arguments import number_in
from laser_odom.tools.quiet import warnings_silenced
from laser_odom.tools.replay_report import DEFAULT_MIN_COVERAGE

PROG = 'laser_odom_tune'


class TuneError(Exception):
    """An input error; ``str(error)`` is the one-line message (exit code 2)."""


class NoUsableTrial(Exception):
    """Every trial failed (exit code 1): there is nothing to recommend."""


def failure_lines(summaries: Sequence[StudySummary]) -> list[str]:
    """Return, per matcher with failed trials, how many and why the first one failed."""
    return [f'{s.matcher}: {s.failed} of {s.trials} trials failed, first {s.failure}'
            for s in summaries if s.failure is not None]


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    p = argparse.ArgumentParser(
        prog=PROG, description='Tune the matchers and pipeline settings - among them what '
        'each scan is matched against, the previous scan or a local map of the recent scans '
        '(reference: scan, local_map) - on your own bags with Optuna, against a reference or '
        'reference-free; write the best as a params file for laser_odom_node.')
    p.add_argument('bags', nargs='+', metavar='BAG', help='ROS 2 or ROS 1 bag')
    p.add_argument('--matchers', help='comma-separated matchers (default: all: '
                   f'{",".join(matcher_names())})')
    p.add_argument('--trials', type=int, default=60, help='trials per matcher (default 60)')
    p.add_argument('--reference', type=Path, action='append', default=[], metavar='REF.tum',
                   help='reference TUM file, one per bag in order (default: the '
                   f'{BAG_GROUND_TRUTH} topic of the bag)')
    p.add_argument('--objective', choices=OBJECTIVES, default='rpe',
                   help='score against the reference: rpe (mean translational RPE + 1 m/rad '
                   'x mean rotational RPE + 0.01 per failed step) or ate (default: rpe)')
    p.add_argument('--reference-free', action='store_true', help='score by map sharpness '
                   '(forced when a bag has no reference)')
    p.add_argument('--odom-agreement', type=float, default=0.0, metavar='WEIGHT',
                   help='reference-free: add WEIGHT x disagreement with wheel odometry')
    p.add_argument('--min-coverage', type=number_in(float, 0.0, 1.0, what='number'),
                   default=DEFAULT_MIN_COVERAGE, metavar='FRACTION',
                   help="least fraction of a bag's duration the reference must cover, "
                   'judged by time span as laser_odom_replay judges it: a keyframe reference '
                   f'that spans the bag covers it (default {DEFAULT_MIN_COVERAGE:g})')
    p.add_argument('--params-file', type=Path, help='starting params file (trial 0)')
    p.add_argument('--space', type=Path, help='YAML of ranges: name: [low, high] or '
                   '[choice, ...]')
    p.add_argument('--output', type=Path, default=Path('tuned.yaml'),
                   help='params file of the best settings (default tuned.yaml)')
    p.add_argument('--study-name', default='laser_odom_tune',
                   help='study name; one study per matcher, NAME-MATCHER')
    p.add_argument('--storage', help='Optuna RDB storage URL (sqlite:///study.db, '
                   'postgresql://...) to resume or share a study')
    p.add_argument('--jobs', type=int, default=1, help='parallel processes (default 1)')
    p.add_argument('--seed', type=int, help='sampler seed')
    p.add_argument('--scan-topic', help='LaserScan topic (default: the only one)')
    p.add_argument('--odom-topic', default=None, help='wheel odometry topic, which every '
                   'bag must have (default: /odom where a bag has it): the odom prior and '
                   '--odom-agreement')
    p.add_argument('--plot', type=Path, help='write a PNG of the studies and best runs')
    p.add_argument('--quiet', action='store_true', help='no progress and no warnings')
    return p


def load_bag(path: str, reference: str | None, scan_topic: str | None,
             odom_topic: str | None) -> RecordedBag:
    """Read one bag (in bag order, as the replay) with the tools' one bag reader."""
    try:
        return read_bag(path, reference, scan_topic, odom_topic, purpose='tuning')
    except ValueError as err:
        raise TuneError(str(err)) from None


def check_reference_overlap(bag: RecordedBag, min_coverage: float) -> None:
    """Raise TuneError when the reference pairs with too few of the bag's scans in time."""
    try:
        check_overlap(bag, bag.name, min_coverage)
    except ValueError as err:
        raise TuneError(str(err)) from None


def load_bags(paths: Sequence[str], references: Sequence[str | None],
              scan_topic: str | None, odom_topic: str | None) -> list[RecordedBag]:
    """Read every bag (also what each ``--jobs`` process calls)."""
    return [load_bag(p, r, scan_topic, odom_topic) for p, r in zip(paths, references)]


def _matchers(text: str | None) -> list[str]:
    """Return the ``--matchers`` list; TuneError for an unknown name."""
    names = matcher_names() if not text else [m.strip() for m in text.split(',') if m.strip()]
    unknown = [m for m in names if m not in matcher_names()]
    if unknown or not names:
        raise TuneError(f'unknown matcher {unknown[0] if unknown else text!r}; valid '
                        f'names: {", ".join(matcher_names())}')
    return list(dict.fromkeys(names))


def _require(module: str, package: str, what: str) -> None:
    """Import ``module`` or raise TuneError naming what to install."""
    try:
        __import__(module)
    except ImportError:
        raise TuneError(f'{what} needs {package}: pip install {package}') from None


def _objective_name(args: argparse.Namespace, bags: list[RecordedBag], warn: Any) -> str:
    """Return the score to use: the ``--objective``, or reference-free without references."""
    odom_weight = args.odom_agreement
    if not math.isfinite(odom_weight) or odom_weight < 0.0:
        raise TuneError(f'--odom-agreement must be a finite weight >= 0, got {odom_weight}')
    missing = [b.name for b in bags if b.reference is None]
    objective = REFERENCE_FREE if args.reference_free or missing else args.objective
    if missing and not args.reference_free:
        warn(f'no reference for {missing[0]} (no --reference, no {BAG_GROUND_TRUTH} topic): '
             'scoring every bag reference-free')
    if odom_weight > 0.0:
        if objective != REFERENCE_FREE:
            raise TuneError('--odom-agreement weighs the reference-free score: add '
                            '--reference-free')
        lacking = [b.name for b in bags if b.odometry is None]
        if lacking:
            raise TuneError(f'--odom-agreement: {lacking[0]} has no /odom Odometry topic '
                            '(name another with --odom-topic)')
    if objective != REFERENCE_FREE:
        for bag in bags:
            check_reference_overlap(bag, args.min_coverage)
    return objective


def tuned_yaml(values: dict[str, Any], summary: StudySummary, header: list[str],
               start: str = 'defaults') -> str:
    """Return the node's params file of ``values``: only what differs from the defaults.

    Each line says in a comment what it was and the score it reached, beside the
    score of the ``start`` (the defaults, or the ``--params-file`` trial 0 ran with);
    matcher settings are nested under ``<matcher>:`` as in ``config/default.yaml``.
    """
    defaults = {spec.name: spec.default for spec in parameter_specs()}
    score = f'score {summary.best:.5g} ({start} {summary.default:.5g})'
    matcher = yaml_value(values['matcher'])
    lines = [f'# {line}' for line in header] + [
        '/**:', '  ros__parameters:', f'    matcher: {matcher}  # best matcher: {score}']
    nested: dict[str, list[str]] = {}
    for name, value in values.items():
        if name == 'matcher' or value == defaults[name]:
            continue
        group, _, leaf = name.rpartition('.')
        nested.setdefault(group, []).append(
            f'{"      " if group else "    "}{leaf}: {yaml_value(value)}  '
            f'# default {yaml_value(defaults[name])}; {score}')
    lines += nested.pop('', [])
    for group, group_lines in nested.items():
        lines += [f'    {group}:'] + group_lines
    return '\n'.join(lines) + '\n'


def write_output(path: Path, text: str) -> None:
    """Check that the node reads the params file as written, then write it atomically."""
    with tempfile.TemporaryDirectory(prefix='laser_odom_tune_check.') as scratch:
        check = Path(scratch) / path.name
        check.write_text(text)
        checked = read_params_files([check])
    if checked.warnings:
        raise TuneError(f'internal error: {path} would warn: {checked.warnings[0]}')
    write_text_atomically(path, text)


def plot(path: Path, job: TuneJob, storage: Any, bags: list[RecordedBag],
         summaries: list[StudySummary]) -> None:
    """Draw each study's scores and each matcher's best run on the first bag (``--plot``)."""
    from laser_odom.tools import plots  # matplotlib: only when asked for
    studies, best = plot_data(job, storage, bags[:1], summaries)
    ref = bags[0].reference
    try:
        plots.plot_study(path, studies, best, None if ref is None else (ref.stamps_ns, ref.poses))
    except plots.PlotError as err:
        raise TuneError(str(err)) from None


def tune(args: argparse.Namespace) -> int:
    """Run the tuning described by parsed arguments; return the exit code."""
    _require('optuna', 'optuna', PROG)
    if args.plot is not None:
        _require('matplotlib', 'matplotlib', f'{PROG} --plot')
    for path in (args.output, args.plot):
        if path is not None and not path.parent.is_dir():
            raise TuneError(f'directory {path.parent} does not exist (for {path})')
    warn = (lambda message: None) if args.quiet else (
        lambda message: print(f'{PROG}: warning: {message}', file=sys.stderr))
    matchers = _matchers(args.matchers)
    if args.reference and len(args.reference) != len(args.bags):
        raise TuneError(f'{len(args.reference)} --reference for {len(args.bags)} bags: give '
                        'one per bag, in order, or none')
    overrides = read_space_file(args.space, matchers) if args.space is not None else {}
    base: dict[str, Any] = {}
    if args.params_file is not None:
        checked = read_params_files([args.params_file], require_section=True)
        for message in checked.warnings:
            warn(message)
        base = {k: v for k, v in checked.values.items() if k != 'matcher'}
    references = [str(r) for r in args.reference] or [None] * len(args.bags)
    loader = partial(load_bags, list(args.bags), references, args.scan_topic, args.odom_topic)
    bags = loader()
    objective = _objective_name(args, bags, warn)
    priors = list(BASE_PRIORS) + [p for p, ok in (
        ('odom', all(b.odometry is not None for b in bags)),
        ('imu', all(b.imu is not None for b in bags))) if ok]
    if base.get('prior', BASE_PRIORS[-1]) not in priors:
        raise TuneError(f'{args.params_file} sets prior {base["prior"]}, but not every bag '
                        'has its topic')
    spaces = {m: matcher_space(m, base, priors, overrides) for m in matchers}
    temporary = tempfile.mkdtemp(prefix='laser_odom_tune.') if (
        args.jobs > 1 and args.storage is None) else None
    url = args.storage or (f'sqlite:///{temporary}/study.db' if temporary else None)
    try:
        storage = open_storage(url)
        definition = {'objective': objective, 'odom_weight': args.odom_agreement or 0.0,
                      'bags': [f'{Path(b.name).name} ({len(b.scans)} scans)' for b in bags],
                      'start': {k: base[k] for k in sorted(base)}}
        job = TuneJob(loader, spaces, base, objective, args.odom_agreement, args.study_name,
                      url, args.seed, sys.stderr.isatty() and not args.quiet, definition)
        existing = run_studies(job, storage, args.trials, args.jobs)
        summaries = summarize(job, storage, existing)
        start = 'default' if args.params_file is None else 'start'
        winner = min(summaries, key=lambda s: s.best if math.isfinite(s.best) else math.inf)
        if not math.isfinite(winner.best):
            print('\n'.join(table_lines(summaries, objective, start) + failure_lines(summaries)))
            raise NoUsableTrial('no trial of ' + ', '.join(matchers) + ' ran on the laser (see '
                                f'the failures above); nothing written to {args.output}')
        header = [f'{PROG}: best of {", ".join(matchers)} on {", ".join(args.bags)}',
                  f'score {objective.replace("_", "-")}, lower is better; study '
                  f'{args.study_name}-{winner.matcher}, {winner.total} trials']
        # The files first: a reader leaving the printed table loses nothing.
        write_output(args.output, tuned_yaml(winner.best_values or {'matcher': winner.matcher},
                                             winner, header, 'defaults' if args.params_file
                                             is None else 'start'))
        if args.plot is not None:
            plot(args.plot, job, storage, bags, summaries)
        print('\n'.join(table_lines(summaries, objective, start) + failure_lines(summaries)))
        print(f'best: {winner.matcher} {winner.best:.5g} ({start} {winner.default:.5g}); '
              f'wrote {args.output}')
        for bag, counts in zip(bags, winner.best_counts):
            print(f'best run on {Path(bag.name).name}: {describe_counts(counts)}')
        if args.plot is not None:
            print(f'wrote {args.plot}')
    finally:
        if temporary is not None:
            shutil.rmtree(temporary, ignore_errors=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Run ``laser_odom_tune``; return the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.trials < 1 or args.jobs < 1:
        parser.error('--trials and --jobs must be at least 1')
    try:
        with reader_may_leave(), warnings_silenced(args.quiet):
            return tune(args)
    except (TuneError, SpaceError, StorageError, StudyMismatchError, BagError,
            ParamsFileError) as err:
        print(f'{PROG}: error: {err}', file=sys.stderr)
        return 2
    except (RuntimeError, NoUsableTrial) as err:  # a --jobs process died, no usable trial
        print(f'{PROG}: error: {err}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f'{PROG}: interrupted; finished trials stay in the storage', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
