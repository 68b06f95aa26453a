"""Node health on ``/diagnostics``: what came in, what was done with it, and how fast.

Once a second the node publishes one ``diagnostic_msgs/DiagnosticStatus`` with what it
runs with (matcher, reference, prior), the pipeline's counters (scans in and processed,
skipped and rejected scans by reason, failed and degenerate matches), processing-time
statistics and the input rate. The
level is judged on the last period only (failure rate, backlog, silence) and on the
recent processing times, so the status recovers as soon as the problem does.

Scans the odometry never saw are said as what happened to them: scans dropped before
reaching the node (missing from the publisher's sequence numbers or the stamps: lost
by the driver or the network; counter ``missed_scans``) and scans not processed
because the node was busy (overwritten in its depth-1 subscription while it matched
an earlier one; ``skipped_backlog``). ``scans skipped`` totals every scan not
processed, by reason in ``skipped: <reason>`` (these two included, under the counter
names that other programs read); a repaired scan was processed and is counted under
its own name.
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass, field
import statistics
from typing import Iterable

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
import numpy as np

from laser_odom.core.configuration.node import NodeConfig
from laser_odom.core.pipeline.estimate import EVENTS, OUTCOMES
from laser_odom.core.preprocess.validation import REJECTIONS


REJECTED_PREFIX = 'rejected_'
"""Prefix of the per-reason rejection counters the node keeps."""

DROPPED = 'missed_scans'
"""Counter of the scans dropped before reaching the node (gaps in the publisher's
sequence numbers and in the stamps)."""

BUSY = 'skipped_backlog'
"""Counter of the scans not processed because the node was busy (overwritten in the
subscription's depth-1 queue)."""

DROPPED_KEY = 'scans dropped before reaching the node'
"""Diagnostics key of the :data:`DROPPED` count."""

BUSY_KEY = 'scans not processed because the node was busy'
"""Diagnostics key of the :data:`BUSY` count."""

SKIP_REASONS = frozenset(REJECTIONS) | {'duplicate_stamp', 'extrinsic_missing', BUSY, DROPPED}
"""Counters of scans that were not processed: invalid, a repeated stamp, no laser
mounting from TF, busy, dropped. A repaired scan (``length_mismatch``, ...) or a
matcher error is processed, so its counter is listed under its own name."""


class ScanGapCounter:
    """Counts the scans that never reached the node's callback, and why, from those that do.

    The subscription keeps only the newest scan, so a scan published while the node
    was matching an earlier one is overwritten by the next. Two gaps between the scans
    that do arrive tell of the others:

    - the publisher's sequence numbers (DDS metadata): scans published but never
      delivered. When the scan that ends the gap waited in the subscription (it was
      received while the node was still busy with the previous one), they were
      overwritten there: :data:`BUSY`; otherwise they were lost on the way (the
      network, or published faster than the subscription is served): :data:`DROPPED`;
    - the stamps: a gap of several scan periods that the sequence numbers do not
      explain holds scans that were never published (lost by the driver, or before a
      relay): :data:`DROPPED`.

    The period is the median of the recent stamp gaps, each divided by the number of
    scans published in it, so a node that is always busy still learns the scanner's
    period. A gap in the stamps longer than ``max_gap_ns`` (a pause) is not taken for
    lost scans, but a gap in the sequence numbers across it is (a node busy for that
    long with one scan - a replay played faster than the node runs - still says what
    it did not process); stamps or sequence numbers going back are not counted, nor
    sequence gaps far longer than the stamps allow (two publishers on one topic). A
    middleware without sequence numbers or reception times leaves only the stamps, and
    every missing scan counts as dropped.
    """

    def __init__(self, window: int = 50, min_samples: int = 5) -> None:
        """Create the counter; stamps count nothing before ``min_samples`` gaps are seen."""
        self._periods: deque[float] = deque(maxlen=window)
        self._min_samples = min_samples
        self._last: int | None = None
        self._last_sequence: int | None = None

    def skipped(self, stamp_ns: int, max_gap_ns: int, sequence: int | None = None,
                waited: bool = False) -> dict[str, int]:
        """Return the scans missing just before the scan stamped ``stamp_ns``, by reason.

        ``sequence`` is its publication sequence number (None if unknown) and
        ``waited`` whether it was received while the node was busy.
        """
        last, self._last = self._last, stamp_ns
        last_sequence, self._last_sequence = self._last_sequence, sequence
        published = 1
        if sequence is not None and last_sequence is not None and sequence > last_sequence:
            published = sequence - last_sequence
        if last is None or stamp_ns <= last:
            if last is not None and stamp_ns < last:
                self._periods.clear()
            return {}
        gap = stamp_ns - last
        enough = len(self._periods) >= self._min_samples
        # statistics.median sorts the 50 floats in C; numpy's converts the deque first,
        # which costs more than the rest of this call, on every scan.
        period = statistics.median(self._periods) if enough else 0.0
        if period > 0.0 and published > 2.0 * gap / period + 1.0:
            published = 1  # more scans than the stamps have room for: two publishers
        undelivered = published - 1
        counts = {BUSY if waited else DROPPED: undelivered}
        if gap <= max_gap_ns:  # a longer gap is a pause: only the sequence numbers count
            self._periods.append(gap / published)
            from_stamps = (int(round(gap / period)) - 1
                           if period > 0.0 and gap > 1.5 * period else 0)
            counts[DROPPED] = counts.get(DROPPED, 0) + max(0, from_stamps - undelivered)
        return {k: v for k, v in counts.items() if v}


@dataclass
class Snapshot:
    """What the diagnostics are computed from, copied under the node's lock."""

    time: float
    received: int
    counters: Counter
    processing_times: np.ndarray
    matcher: str
    prior: str
    scan_topic: str
    latencies: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """Recent times from a scan's receipt to its odometry being published [s]."""
    reference: str = ''
    """What scans are matched against: ``scan`` (the previous one) or ``local_map``."""


def skip_reasons(counters: Counter) -> dict[str, int]:
    """Return the counters that name why a scan was not processed."""
    return {k: v for k, v in sorted(counters.items()) if v and k in SKIP_REASONS}


def other_counts(counters: Counter) -> dict[str, int]:
    """Return the counters of processed scans that are no outcome, rejection or event."""
    return {k: v for k, v in sorted(counters.items()) if v and k not in SKIP_REASONS
            and k not in OUTCOMES and k not in EVENTS and not k.startswith(REJECTED_PREFIX)}


def _milliseconds(seconds: np.ndarray, percentile: float) -> str:
    """Return a percentile of durations in milliseconds, or 'n/a' for none."""
    return f'{np.percentile(seconds, percentile) * 1e3:.2f}' if len(seconds) else 'n/a'


def _values(pairs: Iterable[tuple[str, object]]) -> list[KeyValue]:
    """Return key/value pairs as diagnostic ``KeyValue`` messages."""
    return [KeyValue(key=key, value=str(value)) for key, value in pairs]


class DiagnosticsReporter:
    """Builds the node's status from successive snapshots."""

    def __init__(self, name: str, hardware_id: str, start_time: float) -> None:
        """Create the reporter; the first report covers the time since ``start_time``."""
        self.name = name
        self.hardware_id = hardware_id
        self._previous = Snapshot(start_time, 0, Counter(), np.zeros(0), '', '', '')

    def status(self, now: Snapshot, thresholds: NodeConfig) -> DiagnosticStatus:
        """Return the status for the period since the previous call."""
        before, self._previous = self._previous, now
        period = max(now.time - before.time, 1e-9)
        delta = Counter(now.counters)
        delta.subtract(before.counters)
        received = now.received - before.received
        matches = delta['matched'] + delta['degenerate'] + delta['rejected']
        failure_rate = delta['rejected'] / matches if matches else 0.0
        times = now.processing_times
        median = float(np.median(times)) if len(times) else 0.0
        p95 = float(np.percentile(times, 95)) if len(times) else 0.0

        level, problems = DiagnosticStatus.OK, []

        def raise_level(new_level: bytes, text: str) -> None:
            nonlocal level
            level = max(level, new_level)
            problems.append(text)

        if failure_rate >= thresholds.diagnostics_error_failure_rate and matches:
            raise_level(DiagnosticStatus.ERROR, f'{failure_rate:.0%} of matches failed')
        elif failure_rate >= thresholds.diagnostics_warn_failure_rate and matches:
            raise_level(DiagnosticStatus.WARN, f'{failure_rate:.0%} of matches failed')
        if median >= thresholds.diagnostics_error_processing_time and len(times):
            raise_level(DiagnosticStatus.ERROR, f'median processing time {median * 1e3:.0f} ms')
        elif median >= thresholds.diagnostics_warn_processing_time and len(times):
            raise_level(DiagnosticStatus.WARN, f'median processing time {median * 1e3:.0f} ms')
        if delta[BUSY] > 0:
            raise_level(DiagnosticStatus.WARN, f'{delta[BUSY]} {BUSY_KEY} (matching is '
                                               'slower than the scans arrive)')
        if delta[DROPPED] > 0:
            raise_level(DiagnosticStatus.WARN, f'{delta[DROPPED]} {DROPPED_KEY} (gaps in '
                                               "the publisher's sequence numbers or the scan "
                                               'stamps: lost by the driver or the network)')
        if received == 0:
            raise_level(DiagnosticStatus.WARN, f'no scans received on {now.scan_topic} '
                                               f'in the last {period:.1f} s')

        skipped = skip_reasons(now.counters)
        rejected = {k[len(REJECTED_PREFIX):]: v for k, v in sorted(now.counters.items())
                    if k.startswith(REJECTED_PREFIX)}
        pairs = [
            ('matcher', now.matcher), ('reference', now.reference), ('prior', now.prior),
            ('scans received', now.received), ('scans in', now.counters['scans_in']),
            ('scans processed', now.counters['processed']),
            (BUSY_KEY, now.counters[BUSY]), (DROPPED_KEY, now.counters[DROPPED]),
            ('scans skipped', sum(skipped.values())),
            ('failed matches', now.counters['rejected']),
            ('degenerate matches', now.counters['degenerate']),
            ('failure rate (last period)', f'{failure_rate:.3f}'),
            ('processing time median [ms]', f'{median * 1e3:.2f}'),
            ('processing time p95 [ms]', f'{p95 * 1e3:.2f}'),
            ('latency median [ms]', _milliseconds(now.latencies, 50)),
            ('latency p95 [ms]', _milliseconds(now.latencies, 95)),
            ('input rate [Hz]', f'{received / period:.2f}'),
        ]
        pairs += [(f'skipped: {k}', v) for k, v in skipped.items()]
        pairs += [(f'rejected: {k}', v) for k, v in rejected.items()]
        pairs += [(k, now.counters[k]) for k in EVENTS if now.counters[k]]
        pairs += list(other_counts(now.counters).items())
        return DiagnosticStatus(
            level=level, name=self.name, hardware_id=self.hardware_id,
            message='; '.join(problems) if problems else 'OK', values=_values(pairs))
