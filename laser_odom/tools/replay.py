"""``laser_odom_replay BAG``: run the odometry over a recorded bag, offline or through the node.

By default the scans are fed in-process through the same
:class:`~laser_odom.core.pipeline.odometry.OdometryPipeline` the node runs, with the node's own
parameter file (``--params-file``) and the same prior buffers
(:mod:`laser_odom.core.motion.priors`). With ``--live`` they are published over DDS to a
running ``laser_odom_node`` instead, one at a time (or, with ``--rate R``, at ``R``
times their recorded rate without waiting), and its ``odom`` answers are recorded (see
:mod:`laser_odom.tools.replay_live`).

Outputs: ``--tum`` (one line per processed scan, written atomically), ``--output-bag``
(``/odom`` with covariance and ``/pose``), ``--plot`` (a PNG, :mod:`laser_odom.tools.plots`),
and a summary; ``--reference`` adds how many
poses it pairs with, ATE and RPE (:mod:`laser_odom.core.evaluation.metrics`), and is an input
error when it pairs with less than ``--min-coverage`` of them (the outputs are
written first). A damaged bag is replayed up to the damage, the outputs are written,
and the exit code is 2. Exit codes: 0 ok, 1 runtime failure, 2 input error (missing or
unreadable bag, no scan topic, bad params file, damaged bag, reference that does not
cover the trajectory).
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys
from typing import Any, Callable, Iterator

from laser_odom.core.configuration.node import NodeSettings, PriorConfig, settings_from_params
from laser_odom.core.configuration.pipeline import PRIORS
from laser_odom.core.events import EventLog
from laser_odom.core.matchers import matcher_names
from laser_odom.core.motion.priors import PriorFeed
from laser_odom.core.parameters import ParameterError
from laser_odom.core.pipeline.estimate import OdometryEstimate
from laser_odom.core.pipeline.odometry import OdometryPipeline
from laser_odom.core.pipeline.runner import run_pipeline
from laser_odom.core.scan.laser_scan import LaserScan
from laser_odom.core.trajectory import Trajectory
from laser_odom.io.bag_reader import (
    BagError, BagReader, BagTruncatedError, LASER_SCAN)
from laser_odom.io.errors import BagWriteError, OutputExistsError
from laser_odom.io.params_file import ParamsFileError, read_params_files
from laser_odom.io.text_output import reader_may_leave
from laser_odom.ros.graph import DISCOVERY_TIMEOUT, STARTUP_TIMEOUT
from laser_odom.tools.arguments import number_in
from laser_odom.tools.plots import (
    check_plot_output, plot_replay, PlotError, ScanPointsRecorder)
from laser_odom.tools.quiet import warnings_silenced
from laser_odom.tools.replay_report import (
    DEFAULT_MIN_COVERAGE, print_summary, read_reference, ReplayError, ReplayRecord,
    write_outputs)
from laser_odom.tools.replay_target import ANSWER_TIMEOUT, params_node_name
from laser_odom.tools.stopping import stop_between_scans

PROG = 'laser_odom_replay'
PROGRESS_EVERY = 500
"""Scans between two progress lines (unless --quiet)."""


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    p = argparse.ArgumentParser(
        prog=PROG, description='Run the laser odometry over the scans of a recorded bag, '
        'in-process or (--live) through a running laser_odom_node - each scan matched '
        'against the previous scan or, with reference: local_map in the params file, a '
        'local map of the recent scans; write the trajectory as TUM and/or a bag, and '
        'score it against a reference.')
    p.add_argument('bag', help='ROS 2 bag directory, .db3/.mcap file, or ROS 1 .bag file')
    p.add_argument('--scan-topic', help='LaserScan topic (default: the only one in the bag)')
    p.add_argument('--matcher', choices=matcher_names(),
                   help='scan matcher (overrides the params file)')
    p.add_argument('--params-file', type=Path, help="the node's ROS 2 parameter YAML file")
    p.add_argument('--prior', choices=PRIORS, help='motion prior (overrides the params file)')
    p.add_argument('--odom-topic', help='Odometry topic for --prior odom (default: /odom)')
    p.add_argument('--imu-topic', help='Imu topic for --prior imu (default: the only one)')
    p.add_argument('--tum', type=Path, help='write the trajectory to this TUM file')
    p.add_argument('--output-bag', type=Path,
                   help='write a ROS 2 bag with /odom (Odometry) and /pose (PoseStamped)')
    p.add_argument('--storage', choices=('sqlite3', 'mcap'), default='sqlite3',
                   help='storage of --output-bag (default: sqlite3)')
    p.add_argument('--reference', type=Path,
                   help='reference TUM file: print how many poses it pairs with, ATE '
                   '(SE(2)-aligned) and RPE')
    p.add_argument('--min-coverage', type=number_in(float, 0.0, 1.0, what='number'),
                   default=DEFAULT_MIN_COVERAGE,
                   metavar='FRACTION',
                   help='--reference: fail (exit 2) when the reference covers less than '
                   "this fraction of the run's duration (judged by time span: keyframes "
                   'that span the run cover it) or of its poses within the run pair with '
                   f'no scan; the outputs are written anyway (default: {DEFAULT_MIN_COVERAGE:g})')
    p.add_argument('--plot', type=Path, metavar='PNG',
                   help='after the run, write a PNG: the trajectory (and the SE(2)-aligned '
                   '--reference) over the map the scans make at the estimated poses, and '
                   'the error over time (needs matplotlib). With --live the node sends no '
                   'scan points: the trajectory and the errors only')
    p.add_argument('--live', action='store_true',
                   help='publish the scans to a running laser_odom_node instead')
    p.add_argument('--namespace', metavar='NS',
                   help='--live: the node runs in namespace NS (-r __ns:=NS): node '
                   'NS/laser_odom, topics NS/scan and NS/odom; also the node the params '
                   'file is read for. Default: --live finds the one laser_odom node on the '
                   'graph, in any namespace, with its actual topics')
    p.add_argument('--scan-topic-out',
                   help="--live: scan topic of the node (default: the node's, from the graph)")
    p.add_argument('--odom-topic-in',
                   help="--live: odometry topic of the node (default: the node's, from "
                   'the graph)')
    p.add_argument('--node-name',
                   help='node name (with namespace, if any) the params file is read for, '
                   'as the node reads it; --live: also the node whose ~/reset and '
                   'diagnostics are used (default: laser_odom, or with --live the one found)')
    p.add_argument('--timeout', type=number_in(float, 0.0, 1e6, low_open=True, what='number'),
                   default=None, metavar='S',
                   help='--live: seconds to wait for the odometry of one scan (with '
                   f'--rate: of the last one; default {ANSWER_TIMEOUT:g}), and at most '
                   'for the node to appear, start and subscribe (default: '
                   f'{DISCOVERY_TIMEOUT:g} s to appear, up to {STARTUP_TIMEOUT:g} s while '
                   'it compiles its kernels)')
    p.add_argument('--rate', type=number_in(float, 0.0, 1e6, low_open=True, what='number'),
                   metavar='R',
                   help='--live: play the scans (and prior messages) at R times their '
                   'recorded rate, by their stamps, without waiting for the odometry '
                   '(like ros2 bag play --rate); reports the scans the node skipped. '
                   'Default: lock-step, each scan waits for its odometry')
    p.add_argument('--clock', action='store_true',
                   help="--live: publish /clock (rosgraph_msgs/Clock) with each scan's stamp "
                   'before the scan, for a node run with use_sim_time:=true (like ros2 bag '
                   'play --clock)')
    p.add_argument('--quiet', action='store_true',
                   help='no progress lines and no warnings (errors still show)')
    return p


def load_settings(args: argparse.Namespace) -> NodeSettings:
    """Return what the node would run with: the params file read as the node reads it.

    The file's warnings (unknown names) go to stderr, as the node logs them; a file
    with no section for the node is an error (the node would run on its defaults);
    ``--matcher`` and ``--prior`` override the file.
    """
    values: dict[str, Any] = {}
    if args.params_file is not None:
        checked = read_params_files([args.params_file], params_node_name(args),
                                    require_section=True)
        for warning in checked.warnings:
            warner(args.quiet)(warning)
        values = checked.values
    if args.matcher is not None:
        values['matcher'] = args.matcher
    if args.prior is not None:
        values['prior'] = args.prior
    try:
        return settings_from_params(values)
    except ParameterError as err:
        raise ReplayError(f'bad parameter: {err}') from None


def load_prior_feed(bag: BagReader, prior: str, config: PriorConfig,
                    args: argparse.Namespace) -> PriorFeed:
    """Read the prior's topic from the bag (what is readable of a damaged one)."""
    odometry = imu = None
    if prior == 'odom':
        topic = args.odom_topic
        if topic is None:
            if '/odom' not in bag.topics:
                raise ReplayError(f'{bag.path}: no /odom topic for --prior odom; '
                                  'choose one with --odom-topic')
            topic = '/odom'
        odometry = bag.odometry(topic, strict=False)
    elif prior == 'imu':
        imu = bag.imu(args.imu_topic, strict=False)
    return PriorFeed(prior, config, odometry, imu)


def run_in_process(scans: Iterator[LaserScan], pipeline: OdometryPipeline, feed: PriorFeed,
                   record: ReplayRecord, quiet: bool,
                   points: ScanPointsRecorder | None = None) -> None:
    """Feed every scan through the pipeline, recording each estimate as it comes.

    ``points`` (``--plot``) keeps each estimate's base-frame scan points.
    """
    def progress(count: int) -> None:
        record.scans_read = count
        if not quiet and count % PROGRESS_EVERY == 0:
            print(f'{count} scans replayed so far', file=sys.stderr, flush=True)
        if record.stop is not None:
            record.stop.check()  # Ctrl-C: stop here, between two scans

    def on_estimate(estimate: OdometryEstimate) -> None:
        record.add(estimate.stamp_ns, estimate.pose, estimate.pose_covariance,
                   estimate.status, estimate.processing_time)
        if record.messages is not None:
            record.messages.add_estimate(estimate)
        if points is not None:
            points.add(estimate.scan_points)

    try:
        run_pipeline(pipeline, scans, priors=feed, progress=progress, on_estimate=on_estimate)
    finally:
        record.counters = dict(pipeline.counters)


def warn_on_stderr(message: str) -> None:
    """Print a warning (the pipeline's are already throttled) on stderr."""
    print(f'{PROG}: warning: {message}', file=sys.stderr)


def warner(quiet: bool) -> Callable[[str], None]:
    """Return where the replay's warnings go: stderr, or nowhere with ``--quiet``."""
    return (lambda message: None) if quiet else warn_on_stderr


def check_inputs(args: argparse.Namespace) -> Trajectory | None:
    """Fail early (before the replay) on outputs that cannot be written and a bad reference.

    Returns the ``--reference`` trajectory, read now so that a malformed file stops the
    replay before it starts rather than after the last scan.
    """
    for path in (args.tum, args.output_bag, args.reference):
        if path is not None and not path.parent.is_dir():
            raise ReplayError(f'directory {path.parent} does not exist (for {path})')
    if args.output_bag is not None and args.output_bag.exists():
        raise ReplayError(f'{args.output_bag} exists already; not overwriting it')
    if args.reference is None:
        return None
    if not args.reference.is_file():
        raise ReplayError(f'reference file not found: {args.reference}')
    try:
        return read_reference(args.reference)
    except (OSError, ValueError) as err:
        raise ReplayError(f'cannot read reference {args.reference}: {err}') from None


def write_plot(record: ReplayRecord, points: ScanPointsRecorder | None,
               args: argparse.Namespace, reference: Trajectory | None) -> None:
    """Write ``--plot``, with the reference when there is one."""
    trajectory = record.trajectory()
    plot_replay(args.plot, trajectory.stamps_ns, trajectory.poses,
                None if points is None else points.points,
                None if reference is None else (reference.stamps_ns, reference.poses))


def written_lines(record: ReplayRecord, args: argparse.Namespace) -> list[str]:
    """Return a ``wrote`` line for every file the replay wrote."""
    poses = len(record.stamps_ns)
    lines = []
    if args.tum is not None:
        lines.append(f'wrote {args.tum} ({poses} poses, TUM)')
    if args.output_bag is not None and record.messages is not None:
        lines.append(f'wrote {args.output_bag} ({poses} /odom and /pose messages, '
                     f'{args.storage})')
    if args.plot is not None:
        lines.append(f'wrote {args.plot}')
    return lines


def replay(args: argparse.Namespace) -> int:
    """Run the replay described by parsed arguments; return the exit code."""
    reference = check_inputs(args)
    if args.plot is not None:
        check_plot_output(args.plot)
    settings = load_settings(args)
    config, prior_config = settings.pipeline, settings.priors
    record = ReplayRecord(live=args.live, prior=config.motion.prior,
                          max_scan_gap=config.motion.max_scan_gap)
    if args.output_bag is not None:
        from laser_odom.ros.recording import MessageRecorder  # rclpy: only when asked for
        record.messages = MessageRecorder(settings.node)
    damage: BagTruncatedError | None = None
    points = ScanPointsRecorder() if args.plot is not None and not args.live else None
    with BagReader(args.bag) as bag, stop_between_scans() as record.stop:
        topic = bag.select_topic(LASER_SCAN, args.scan_topic)
        record.scans_in_bag = bag.message_count(topic)
        if record.scans_in_bag == 0:
            raise ReplayError(f'{args.bag}: 0 scans on {topic}; a replay needs a bag with scans')
        prior = config.motion.prior
        feed = load_prior_feed(bag, prior, prior_config, args)
        try:
            if args.live:
                from laser_odom.tools.replay_live import run_live
                run_live(bag.scans(topic), feed, record, args)
            else:
                events = EventLog(warner(args.quiet))
                run_in_process(bag.scans(topic), OdometryPipeline(config, events=events),
                               feed, record, args.quiet, points)
        except BagTruncatedError as err:
            damage = err
        except KeyboardInterrupt:
            record.interrupted = True
    if record.scans_read == 0 and damage is None and not record.interrupted:
        raise ReplayError(f'{args.bag}: 0 scans on {topic}; a replay needs a bag with scans')
    write_outputs(record, args)
    if args.plot is not None:
        write_plot(record, points, args, reference)
    problem = ''
    try:
        print_summary(record, args, topic, config.matcher if not args.live else None,
                      reference)
    except ReplayError as err:  # e.g. a reference that hardly covers the trajectory
        if damage is None:
            raise
        problem = f'; {err}'
    finally:
        if not args.quiet:  # after the summary they illustrate
            for line in written_lines(record, args):
                print(line, flush=True)
    if damage is not None:
        raise ReplayError(f'{damage}; {len(record.stamps_ns)} scans processed'
                          + (', outputs written' if args.tum or args.output_bag else '')
                          + problem)
    return 130 if record.interrupted else 0


def main(argv: list[str] | None = None) -> int:
    """Run ``laser_odom_replay``; return the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.rate is not None and not args.live:
        parser.error('--rate needs --live (it plays the scans to a running node)')
    if args.clock and not args.live:
        parser.error('--clock needs --live (it sets the sim time of a running node)')
    try:
        with reader_may_leave(), warnings_silenced(args.quiet):
            return replay(args)
    except (ReplayError, BagError, ParamsFileError, OutputExistsError, PlotError) as err:
        print(f'{PROG}: error: {err}', file=sys.stderr)
        return 2
    except BagWriteError as err:
        print(f'{PROG}: error: {err}', file=sys.stderr)
        return 1


if __name__ == '__main__':
    sys.exit(main())
