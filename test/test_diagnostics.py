"""``/diagnostics`` wording: scans dropped before reaching the node, or not processed.

Scans not processed because the node was busy are said so; the keys other programs
read stay.
"""

from collections import Counter

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np

from laser_odom.core.configuration.node import NodeConfig
from laser_odom.ros.diagnostics import (
    BUSY, BUSY_KEY, DiagnosticsReporter, DROPPED, DROPPED_KEY, ScanGapCounter, Snapshot)

# Keys read by laser_odom.tools.replay_live, laser_odom.tools.bench_live and test_node.
PARSED_KEYS = ('scans received', 'scans in', 'scans processed', 'scans skipped',
               'failed matches', 'degenerate matches', 'latency median [ms]',
               'latency p95 [ms]', 'skipped: skipped_backlog', 'skipped: missed_scans')


def _status(reporter: DiagnosticsReporter, time: float, received: int,
            **counts: int) -> tuple[DiagnosticStatus, dict[str, str]]:
    snapshot = Snapshot(time, received, Counter(counts), np.array([0.01, 0.02]), 'nicp',
                        'constant_velocity', '/scan', latencies=np.array([0.01, 0.03]))
    status = reporter.status(snapshot, NodeConfig())
    return status, {kv.key: kv.value for kv in status.values}


def test_busy_and_dropped_scans_are_said_as_what_happened():
    reporter = DiagnosticsReporter('laser_odom: odometry', 'base_link', 0.0)
    status, values = _status(reporter, 1.0, 10, scans_in=10, processed=10, matched=10)
    assert status.message == 'OK'
    assert values[BUSY_KEY] == values[DROPPED_KEY] == values['scans skipped'] == '0'
    status, values = _status(reporter, 2.0, 20, scans_in=15, processed=15, matched=15,
                             skipped_backlog=5, missed_scans=3)
    assert status.level == DiagnosticStatus.WARN
    assert '5 scans not processed because the node was busy' in status.message
    assert '3 scans dropped before reaching the node' in status.message
    assert 'skipped' not in status.message and 'missed' not in status.message
    assert BUSY_KEY == 'scans not processed because the node was busy'
    assert DROPPED_KEY == 'scans dropped before reaching the node'
    assert values[BUSY_KEY] == '5' and values[DROPPED_KEY] == '3'
    for key in PARSED_KEYS:
        assert key in values, key
    assert values['skipped: skipped_backlog'] == '5' and values['skipped: missed_scans'] == '3'
    assert values['scans skipped'] == '8'
    # The next period has neither: the status recovers, the totals stay.
    status, values = _status(reporter, 3.0, 30, scans_in=25, processed=25, matched=25,
                             skipped_backlog=5, missed_scans=3)
    assert status.message == 'OK' and values[BUSY_KEY] == '5'


def test_a_repaired_scan_is_processed_not_skipped():
    reporter = DiagnosticsReporter('laser_odom: odometry', 'base_link', 0.0)
    status, values = _status(reporter, 1.0, 10, scans_in=10, processed=9, matched=9,
                             length_mismatch=10, empty_scan=1, matcher_error=2)
    assert values['scans skipped'] == '1' and values['skipped: empty_scan'] == '1'
    assert values['length_mismatch'] == '10' and 'skipped: length_mismatch' not in values
    assert values['matcher_error'] == '2'


PERIOD = 100_000_000
"""Scan period of the gap-counter tests [ns]."""


def test_gap_counter_counts_scans_dropped_on_the_way():
    """Without sequence numbers, a gap in the stamps is all there is to go on."""
    counter = ScanGapCounter(min_samples=3)
    stamps = [i * PERIOD for i in (0, 1, 2, 3, 4, 7, 8, 20, 21, 19, 20, 21, 22, 23, 25)]
    # 7: two dropped; 20: a pause longer than max_gap_ns; 19: back in time, period relearnt
    assert [counter.skipped(s, 10 * PERIOD) for s in stamps] == [
        {}, {}, {}, {}, {}, {DROPPED: 2}, {}, {}, {}, {}, {}, {}, {}, {}, {DROPPED: 1}]


def test_gap_counter_tells_busy_from_dropped_by_sequence_and_wait():
    """Scans published but overwritten while the node was busy are not network losses."""
    counter = ScanGapCounter(min_samples=3)
    arrivals = [  # stamp index, publication sequence number, waited in the subscription
        (0, 1, False), (1, 2, False), (2, 3, False), (3, 4, False),
        (5, 6, True),  # one overwritten while busy
        (7, 8, False),  # one lost on the network
        (10, 9, False),  # two never published (the driver lost them)
        (13, 11, True),  # one overwritten, one never published
    ]
    # always busy from here on: every other scan; the period is still known
    arrivals += [(13 + 2 * k, 11 + 2 * k, True) for k in range(1, 30)]
    counts = [counter.skipped(i * PERIOD, 10 * PERIOD, seq, waited)
              for i, seq, waited in arrivals]
    assert counts[:8] == [{}, {}, {}, {}, {BUSY: 1}, {DROPPED: 1}, {DROPPED: 2},
                          {BUSY: 1, DROPPED: 1}]
    assert counts[8:] == [{BUSY: 1}] * 29


def test_gap_counter_ignores_sequence_numbers_the_stamps_cannot_hold():
    """Two publishers on one topic interleave their numbers: the stamps decide."""
    counter = ScanGapCounter(min_samples=3)
    for i in range(6):
        assert counter.skipped(i * PERIOD, 10 * PERIOD, i + 1) == {}
    assert counter.skipped(6 * PERIOD, 10 * PERIOD, 500, True) == {}
    assert counter.skipped(8 * PERIOD, 10 * PERIOD, 3, False) == {DROPPED: 1}


def test_gap_counter_counts_sequence_gaps_across_a_long_stamp_gap():
    """Issue 30.10: a node busy with one scan while a fast replay sent many still counts them.

    The stamps jump by more than max_gap_ns (a pause, by the stamps alone), but the
    sequence numbers say the scans in between were published: overwritten while busy.
    Without sequence numbers the long gap stays a pause.
    """
    counter = ScanGapCounter(min_samples=3)
    for i in range(5):
        assert counter.skipped(i * PERIOD, 10 * PERIOD, i + 1) == {}
    assert counter.skipped(60 * PERIOD, 10 * PERIOD, 61, True) == {BUSY: 55}
    assert counter.skipped(61 * PERIOD, 10 * PERIOD, 62) == {}
    plain = ScanGapCounter(min_samples=3)
    for i in (0, 1, 2, 3, 4, 60):
        assert plain.skipped(i * PERIOD, 10 * PERIOD) == {}
