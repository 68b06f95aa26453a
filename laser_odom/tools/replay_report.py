"""Results of ``laser_odom_replay``: the record of estimates, its outputs and the summary."""

from __future__ import annotations

import argparse
from collections import Counter
from dataclasses import dataclass, field
import sys
from typing import Any

import numpy as np

from laser_odom.core.metrics import associate, distance_travelled, evaluate
from laser_odom.core.pipeline import OUTCOMES
from laser_odom.core.trajectory import Trajectory
from laser_odom.io.bag_writer import write_message_bag
from laser_odom.io.tum import read_tum, TumFormatError, write_tum


DEFAULT_MIN_COVERAGE = 0.5
"""Least fraction of the estimated poses a ``--reference`` must pair with
(``--min-coverage``): an ATE over a few shared stamps says nothing about the run."""


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
    if record.live:
        counts = record.counters
        failed = counts.get('rejected', 'n/a')
        degenerate = counts.get('degenerate', 'n/a')
        how = ('sent to the live node' if record.rate is None else
               f'played to the live node at {record.rate:g}x their recorded rate')
        lines = [f'scans {record.scans_read} of {topic} {how}: odometry '
                 f'received for {processed}, failed (rejected) {failed}, degenerate '
                 f'{degenerate} (from its diagnostics), no answer {counts.get("no_answer", 0)}']
        lines += _node_lines(record)
    else:
        statuses = Counter(record.statuses)
        lines = [f'scans {record.scans_read} from {topic} ({matcher}): processed {processed}, '
                 f'matched {statuses["matched"]}, degenerate {statuses["degenerate"]}, '
                 f'failed (rejected) {statuses["rejected"]}, skipped {skipped}']
        reasons = {k: v for k, v in sorted(record.counters.items())
                   if v and k not in OUTCOMES}
        if reasons:
            lines.append('counters: ' + ', '.join(f'{k} {v}' for k, v in reasons.items()))
    label = 'round-trip latency per scan' if record.live else 'processing time per scan'
    lines.append(f'{label}: {_milliseconds(record.times)}')
    lines.append(f'estimated path length {distance_travelled(record.trajectory()):.2f} m')
    return lines


def _node_lines(record: ReplayRecord) -> list[str]:
    """Return what the live node said about this run in its diagnostics."""
    node = record.node
    lines = []
    if record.late > 0.05:
        lines.append(f'playback: a scan was published up to {record.late * 1e3:.0f} ms after '
                     'its time (the replay could not keep the rate)')
    if not node:
        return lines + ['node diagnostics: no report received (processed and skipped '
                        'scans unknown)']
    return lines + [
        f'node (its /diagnostics, this run): received {node["received"]}, processed '
        f'{node["processed"]}, skipped {node["busy"]} (not processed because the node was '
        f'busy), dropped {node["dropped"]} (before reaching the node); latency receipt -> '
        f'publish median {node["latency_median_ms"]} ms, p95 {node["latency_p95_ms"]} ms '
        '(its recent scans)']


def _percent(part: int, whole: int) -> str:
    """Return ``part`` as a rounded percentage of ``whole`` ('0' for no whole)."""
    return f'{100.0 * part / whole:.0f}' if whole else '0'


def check_coverage(record: ReplayRecord, reference_path: Any, reference: Trajectory,
                   min_coverage: float) -> str:
    """Return the line saying how many estimated poses the reference pairs with.

    Raises :class:`ReplayError` when that is less than ``min_coverage`` of them (a
    reference of another run, another clock, or a few keyframes only).
    """
    estimate = record.trajectory()
    total = len(estimate)
    paired = len(associate(estimate, reference)[0])
    if total == 0 and min_coverage > 0.0:
        raise ReplayError(f'no estimated poses to compare with reference {reference_path}')
    if paired < min_coverage * total:
        raise ReplayError(f'reference {reference_path} covers only {paired} of {total} poses '
                          f'({_percent(paired, total)} %) - below --min-coverage '
                          f'{min_coverage:g}')
    return (f'reference {reference_path}: {paired} of {total} poses paired '
            f'({_percent(paired, total)} %)')


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
    travelled = distance_travelled(reference)
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
                  matcher: str | None) -> None:
    """Print the summary (and the reference metrics with ``--reference``) to stdout.

    Raises :class:`ReplayError` when the reference cannot be compared or covers less
    than ``--min-coverage`` of the estimated poses (after the summary is printed).
    """
    for line in summary_lines(record, topic, matcher):
        print(line)
    sys.stdout.flush()  # the summary comes before any error line on stderr
    if args.reference is None:
        return
    min_coverage = float(getattr(args, 'min_coverage', DEFAULT_MIN_COVERAGE))
    try:
        reference = read_reference(args.reference)
        print(check_coverage(record, args.reference, reference, min_coverage))
        lines = reference_lines(record, args.reference, reference) if record.stamps_ns else []
    except ValueError as err:
        raise ReplayError(f'cannot compare with {args.reference}: {err}') from None
    for line in lines:
        print(line)
    sys.stdout.flush()
