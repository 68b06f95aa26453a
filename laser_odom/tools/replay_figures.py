"""The node's own figures of a live replay, from its ``/diagnostics`` reports.

``laser_odom_replay --live`` reads a report before the first scan and one after the
last; the difference, key by key, is what the node counted for the run (see
:attr:`laser_odom.tools.replay_report.ReplayRecord.node`).
"""

from __future__ import annotations

from typing import Any

from laser_odom.ros.diagnostics import BUSY_KEY, DROPPED_KEY
from laser_odom.tools.replay_report import ReplayRecord


def count(report: dict[str, str] | None, key: str) -> int:
    """Return an integer diagnostics value (0 when absent)."""
    try:
        return int(float((report or {}).get(key, '0')))
    except ValueError:
        return 0


LATENCY_KEYS = ('latency median [ms]', 'latency p95 [ms]')
"""Diagnostics keys of the node's receipt-to-publish latency."""

COUNT_KEYS = {'received': 'scans received', 'processed': 'scans processed',
              'busy': BUSY_KEY, 'dropped': DROPPED_KEY, 'prior_missing': 'prior_missing'}
"""Diagnostics keys of the counts reported for a live run (see ReplayRecord.node)."""


def node_figures(before: dict[str, str], after: dict[str, str]) -> dict[str, Any]:
    """Return a run's figures from the node's reports before and after it (by key)."""
    figures: dict[str, Any] = {name: count(after, key) - count(before, key)
                               for name, key in COUNT_KEYS.items()}
    figures['latency_median_ms'], figures['latency_p95_ms'] = (
        after.get(key, 'n/a') for key in LATENCY_KEYS)
    return figures


def read_report(client: Any, before: dict[str, str] | None, record: ReplayRecord) -> None:
    """Read the node's figures of the run from a report after its last answer.

    ``client`` is the replay's ROS side (``diagnostics_after``, ``diagnostics_count``).
    """
    after = client.diagnostics_after(client.diagnostics_count)
    if before is None or after is None:
        return
    if count(after, 'scans processed') - count(before, 'scans processed') < len(
            record.stamps_ns):  # a report from before the last scan was processed
        after = client.diagnostics_after(client.diagnostics_count) or after
    for key, name in (('failed matches', 'rejected'),
                      ('degenerate matches', 'degenerate')):
        record.counters[name] = count(after, key) - count(before, key)
    record.node = node_figures(before, after)
