"""Results of ``laser_odom_replay``: the record of estimates, its outputs and the summary."""

from __future__ import annotations

import argparse
from collections import Counter
from dataclasses import dataclass, field
import sys
from typing import Any

import numpy as np

from laser_odom.core.evaluation.coverage import reference_coverage
from laser_odom.core.evaluation.metrics import distance_between, distance_travelled, evaluate
from laser_odom.core.pipeline.estimate import OUTCOMES
from laser_odom.core.trajectory import Trajectory
from laser_odom.io.bag_writer import write_message_bag
from laser_odom.io.tum import read_tum, TumFormatError, write_tum


DEFAULT_MIN_COVERAGE = 0.5
"""Least share of the run's duration a ``--reference`` must cover (``--min-coverage``,
judged by time span: :mod:`laser_odom.core.evaluation.coverage`): an ATE over a few shared stamps
says nothing about the run."""


class ReplayError(Exception):
    """A user error stopping the replay; ``str(error)`` is the one-line message."""


@dataclass
class ReplayRecord:
    """What the replay produced: one entry per processed scan, plus run counters."""

    stamps_ns: list[int] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)
    covariances: list[np.ndarray] = field(default_factory=list)
    statuses: list[str] = field(default_factory=list)
    times: list[float] = field(default_factory=list)
    scans_read: int = 0
    counters: dict[str, int] = field(default_factory=dict)
    live: bool = False
    rate: float | None = None
    """``--live --rate``: the playback rate (None: lock-step)."""
    node: dict[str, Any] = field(default_factory=dict)
    """``--live``: this run's figures from the node's ``/diagnostics`` (keys ``received``,
    ``processed``, ``busy``, ``dropped`` as counts; ``latency_median_ms``,
    ``latency_p95_ms`` as text); empty when no report came."""
    late: float = 0.0
    """``--live --rate``: the most [s] a scan was published after its time."""
    after_last: int = 0
    """``--live --rate``: scans sent after the last one the node answered (it never saw
    them, so its diagnostics cannot count them)."""
    node_name: str = ''
    sent_topic: str = ''
    """``--live``: the node driven and the topic its scans went to."""
    scans_in_bag: int | None = None
    """The scan topic's message count by the bag's index (None: unknown)."""
    interrupted: bool = False
    """The run was stopped by Ctrl-C: the outputs hold the scans processed until then."""
    stop: Any = None
    """The Ctrl-C request checked after each scan (:mod:`laser_odom.tools.stopping`)."""
    prior: str = 'none'
    max_scan_gap: float = 0.0
    """The motion prior and ``max_scan_gap`` the run used (offline)."""
    messages: Any = None
    """The node's serialised messages for ``--output-bag`` (a ``MessageRecorder``)."""

    def add(self, stamp_ns: int, pose: np.ndarray, covariance: np.ndarray, status: str,
            seconds: float) -> None:
        """Record the estimate of one processed scan."""
        self.stamps_ns.append(int(stamp_ns))
        self.poses.append(np.asarray(pose, dtype=float))
        self.covariances.append(np.asarray(covariance, dtype=float))
        self.statuses.append(status)
        self.times.append(float(seconds))

    def trajectory(self) -> Trajectory:
        """Return the estimated poses, one per processed scan."""
        return Trajectory(np.asarray(self.stamps_ns, dtype=np.int64),
                          np.asarray(self.poses, dtype=float).reshape(-1, 3))

    def covariance_array(self) -> np.ndarray:
        """Return the pose covariances as an (N, 3, 3) array."""
        return np.asarray(self.covariances, dtype=float).reshape(-1, 3, 3)


def write_outputs(record: ReplayRecord, args: argparse.Namespace) -> None:
    """Write ``--tum`` (atomically) and ``--output-bag`` from what was processed.

    The bag holds the node's own ``/odom`` and ``/pose`` messages, as recorded by
    ``record.messages`` (:class:`laser_odom.ros.recording.MessageRecorder`).
    """
    if args.tum is not None:
        write_tum(args.tum, record.trajectory())
    if args.output_bag is not None and record.messages is not None:
        write_message_bag(args.output_bag, record.messages.topics(), storage=args.storage)


def _milliseconds(seconds: list[float]) -> str:
    """Return 'median X ms, p95 Y ms' of durations in seconds."""
    if not seconds:
        return 'n/a'
    times = np.asarray(seconds) * 1e3
    return f'median {np.median(times):.2f} ms, p95 {np.percentile(times, 95):.2f} ms'


def summary_lines(record: ReplayRecord, topic: str, matcher: str | None) -> list[str]:
    """Return the run summary: scan counts by outcome and the time per scan."""
    processed = len(record.statuses)
    skipped = record.scans_read - processed
    lines = _interruption_lines(record)
    if record.live:
        counts = record.counters
        failed = counts.get('rejected', 'n/a')
        degenerate = counts.get('degenerate', 'n/a')
        where = f'{record.node_name or "the live node"}'
        if record.sent_topic:
            where += f' on {record.sent_topic}'
        how = (f'sent to {where}' if record.rate is None else
               f'played to {where} at {record.rate:g}x their recorded rate')
        lines += [f'scans {record.scans_read} of {topic} {how}: odometry '
                  f'received for {processed}, failed (rejected) {failed}, degenerate '
                  f'{degenerate} (from its diagnostics), no answer {counts.get("no_answer", 0)}']
        lines += _node_lines(record)
    else:
        statuses = Counter(record.statuses)
        lines += [f'scans {record.scans_read} from {topic} ({matcher}): processed {processed}, '
                  f'matched {statuses["matched"]}, degenerate {statuses["degenerate"]}, '
                  f'failed (rejected) {statuses["rejected"]}, skipped {skipped}']
        reasons = {k: v for k, v in sorted(record.counters.items())
                   if v and k not in OUTCOMES}
        if reasons:
            lines.append('counters: ' + ', '.join(f'{k} {v}' for k, v in reasons.items()))
        lines += _prior_lines(record, statuses)
    label = 'round-trip latency per scan' if record.live else 'processing time per scan'
    lines.append(f'{label}: {_milliseconds(record.times)}')
    lines.append(f'estimated path length {distance_travelled(record.trajectory()):.2f} m')
    return lines


def _interruption_lines(record: ReplayRecord) -> list[str]:
    """Return the line that says the run was cut short (Ctrl-C), first in the summary."""
    if not record.interrupted:
        return []
    total = (f' of the {record.scans_in_bag} in the bag' if record.scans_in_bag is not None
             else '')
    return [f'INTERRUPTED (Ctrl-C) after {record.scans_read} scans{total}: the figures '
            'and outputs cover only the scans before it']


def _prior_lines(record: ReplayRecord, statuses: Counter) -> list[str]:
    """Return how often the motion prior predicted a match, and why it did not.

    A prior dropped on most steps (scans further apart than ``max_scan_gap``) changes
    nothing, which the ATE alone does not tell.
    """
    if record.prior == 'none':
        return []
    matches = statuses['matched'] + statuses['degenerate'] + statuses['rejected']
    gaps = record.counters.get('scan_gap', 0)
    missing = record.counters.get('prior_missing', 0)
    used = max(matches - gaps - missing, 0)
    line = (f'motion prior {record.prior}: predicted {used} of {matches} matches; dropped '
            f'on {gaps} (longer than max_scan_gap {record.max_scan_gap:g} s between scans)')
    if record.prior in ('odom', 'imu'):
        line += f', missing on {missing}'
    lines = [line]
    if matches and gaps > matches / 2:
        gap = float(np.median(np.diff(record.stamps_ns))) * 1e-9
        lines.append(f'note: the scans are a median {gap:.2f} s apart, so the prior was '
                     f'dropped on most steps: raise max_scan_gap above {gap:.2f} s to predict '
                     'over such gaps' + ('' if record.prior == 'odom' else
                                         ', or use the wheel odometry (--prior odom)'))
    return lines


def _node_lines(record: ReplayRecord) -> list[str]:
    """Return what the live node said about this run in its diagnostics.

    With ``--rate`` every scan sent is accounted for: answered, not processed because
    the node was busy, dropped before reaching it, sent after the last one it took (it
    never saw them, so it cannot count them), or - should the rest not add up - not
    explained.
    """
    node = record.node
    lines = []
    if record.late > 0.05:
        lines.append(f'playback: a scan was published up to {record.late * 1e3:.0f} ms after '
                     'its time (the replay could not keep the rate)')
    if not node:
        return lines + ['node diagnostics: no report received (processed and skipped '
                        'scans unknown)']
    prior = (f'; motion prior {record.prior} missing or stale on {node["prior_missing"]} '
             'scans' if record.prior in ('odom', 'imu') and 'prior_missing' in node else '')
    lines.append(
        f'node (its /diagnostics, this run): received {node["received"]}, processed '
        f'{node["processed"]}, skipped {node["busy"]} (not processed because the node was '
        f'busy), dropped {node["dropped"]} (before reaching the node); latency receipt -> '
        f'publish median {node["latency_median_ms"]} ms, p95 {node["latency_p95_ms"]} ms '
        f'(its recent scans){prior}')
    if record.rate is not None:
        lines.append(_accounting_line(record))
    return lines


def _accounting_line(record: ReplayRecord) -> str:
    """Return where every scan sent at ``--rate`` went; the parts add up to the scans sent."""
    node = record.node
    answered = len(record.stamps_ns)
    sent = answered + record.counters.get('no_answer', 0)
    unexplained = sent - answered - node['busy'] - node['dropped'] - record.after_last
    parts = [f'{answered} answered', f'{node["busy"]} skipped by the busy node',
             f'{node["dropped"]} dropped before reaching it',
             f'{record.after_last} sent after the last one it took (never seen by it)']
    if unexplained:
        parts.append(f'{unexplained} not explained (answers lost, or scans it skipped as '
                     'invalid)')
    return f'scans sent {sent} = ' + ' + '.join(parts)


def check_coverage(record: ReplayRecord, reference_path: Any, reference: Trajectory,
                   min_coverage: float) -> str:
    """Return the line saying how much of the run the reference covers.

    Coverage is judged by time span (:mod:`laser_odom.core.evaluation.coverage`): a reference of
    keyframes that spans the run covers it. Raises :class:`ReplayError` when it covers
    less than ``min_coverage`` of the run's duration (a reference of another run,
    another clock, or one that stops early).
    """
    coverage = reference_coverage(np.asarray(record.stamps_ns, dtype=np.int64), reference)
    if coverage.total == 0 and min_coverage > 0.0:
        raise ReplayError(f'no estimated poses to compare with reference {reference_path}')
    if coverage.fraction < min_coverage:
        raise ReplayError(f'reference {reference_path}: {coverage.shortfall()} - below '
                          f'--min-coverage {min_coverage:g}')
    return f'reference {reference_path}: {coverage.describe()}'


def read_reference(reference_path: Any) -> Trajectory:
    """Read a reference TUM file; ValueError when it is malformed."""
    try:
        return read_tum(reference_path)
    except TumFormatError as err:
        raise ValueError(str(err)) from None


def reference_lines(record: ReplayRecord, reference_path: Any,
                    reference: Trajectory | None = None) -> list[str]:
    """Return ATE and RPE against a reference TUM file; ValueError when not comparable."""
    if reference is None:
        reference = read_reference(reference_path)
    errors = evaluate(record.trajectory(), reference)
    # The reference's path over the scans processed, not over the whole bag (Ctrl-C).
    travelled = distance_between(reference, min(record.stamps_ns), max(record.stamps_ns))
    share = f' = {100 * errors.ate_rms / travelled:.2f} % of' if travelled > 0 else ' over'
    return [
        f'reference {reference_path}: ATE {errors.ate_rms:.4f} m (RMS, SE(2)-aligned, '
        f'{errors.pairs} poses){share} {travelled:.2f} m travelled',
        f'RPE over {errors.steps} steps: translation mean {errors.rpe_trans_mean:.4f} m, '
        f'RMS {errors.rpe_trans_rms:.4f} m; rotation mean {errors.rpe_rot_mean:.3f} deg, '
        f'RMS {errors.rpe_rot_rms:.3f} deg; failed steps {errors.failed_steps} '
        '(> 0.5 m or > 10 deg)',
    ]


def print_summary(record: ReplayRecord, args: argparse.Namespace, topic: str,
                  matcher: str | None, reference: Trajectory | None = None) -> None:
    """Print the summary (and the reference metrics with ``--reference``) to stdout.

    ``reference`` is the ``--reference`` already read (else it is read here). Raises
    :class:`ReplayError` when the reference cannot be compared or covers less than
    ``--min-coverage`` of the run (after the summary is printed).
    """
    for line in summary_lines(record, topic, matcher):
        print(line)
    sys.stdout.flush()  # the summary comes before any error line on stderr
    if args.reference is None:
        return
    min_coverage = float(getattr(args, 'min_coverage', DEFAULT_MIN_COVERAGE))
    try:
        if reference is None:
            reference = read_reference(args.reference)
        print(check_coverage(record, args.reference, reference, min_coverage))
        lines = reference_lines(record, args.reference, reference) if record.stamps_ns else []
    except ValueError as err:
        raise ReplayError(f'cannot compare with {args.reference}: {err}') from None
    for line in lines:
        print(line)
    sys.stdout.flush()
