"""Results of ``laser_odom_replay``: the record of estimates, its outputs and the summary."""

from __future__ import annotations

import argparse
from collections import Counter
from dataclasses import dataclass, field
import sys
from typing import Any, Mapping

import numpy as np

from laser_odom.core.metrics import distance_travelled, evaluate
from laser_odom.core.pipeline import OUTCOMES
from laser_odom.core.trajectory import Trajectory
from laser_odom.io.bag_writer import write_bag
from laser_odom.io.tum import read_tum, TumFormatError, write_tum


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


def write_outputs(record: ReplayRecord, args: argparse.Namespace,
                  values: Mapping[str, Any]) -> None:
    """Write ``--tum`` (atomically) and ``--output-bag`` from what was processed."""
    trajectory = record.trajectory()
    if args.tum is not None:
        write_tum(args.tum, trajectory)
    if args.output_bag is not None:
        write_bag(args.output_bag, odometry={'/odom': trajectory}, poses={'/pose': trajectory},
                  covariances={'/odom': record.covariance_array()}, storage=args.storage,
                  odom_frame=str(values.get('odom_frame', 'odom')),
                  base_frame=str(values.get('base_frame', 'base_link')))


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
        lines = [f'scans {record.scans_read} of {topic} sent to the live node: odometry '
                 f'received for {processed}, failed (rejected) {failed}, degenerate '
                 f'{degenerate} (from its diagnostics), no answer {counts.get("no_answer", 0)}']
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


def reference_lines(record: ReplayRecord, reference_path: Any) -> list[str]:
    """Return ATE and RPE against a reference TUM file; ValueError when not comparable."""
    try:
        reference = read_tum(reference_path)
    except TumFormatError as err:
        raise ValueError(str(err)) from None
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
    """Print the summary (and the reference metrics with ``--reference``) to stdout."""
    for line in summary_lines(record, topic, matcher):
        print(line)
    if args.reference is not None and record.stamps_ns:
        try:
            lines = reference_lines(record, args.reference)
        except ValueError as err:
            raise ReplayError(f'cannot compare with {args.reference}: {err}') from None
        for line in lines:
            print(line)
    sys.stdout.flush()  # the summary comes before any error line on stderr
