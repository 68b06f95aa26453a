"""Counted, throttled warnings: bad input is reported, never floods the log.

Every event (a skipped scan, a rejected match, a fallback) increments a counter per
reason, which the node publishes on /diagnostics and the replay prints in its summary.
Messages go to a sink (the node's logger, the replay's stderr) at most once per
``period`` seconds per reason, with the count since the last message; reasons marked
``once`` are said only the first time.
"""

from __future__ import annotations

from collections import Counter
import logging
import time
from typing import Callable

Sink = Callable[[str], None]

_LOGGER = logging.getLogger('laser_odom')


class EventLog:
    """Per-reason counters plus throttled messages about them."""

    def __init__(self, sink: Sink | None = None, period: float = 10.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        """Create the log; messages go to ``sink`` (default: the ``laser_odom`` logger)."""
        self.counters: Counter[str] = Counter()
        self.sink: Sink = sink if sink is not None else _LOGGER.warning
        self.period = period
        self.clock = clock
        self._last_said: dict[str, float] = {}
        self._count_at_last: dict[str, int] = {}

    def count(self, reason: str, amount: int = 1) -> None:
        """Count an event without a message."""
        self.counters[reason] += amount

    def warn(self, reason: str, message: str, once: bool = False) -> None:
        """Count an event and say ``message``, throttled per reason."""
        self.counters[reason] += 1
        now = self.clock()
        last = self._last_said.get(reason)
        if last is not None and (once or now - last < self.period):
            return
        total = self.counters[reason]
        since = total - self._count_at_last.get(reason, 0)
        suffix = ''
        if last is not None and since > 1:
            suffix = f' ({since} times in the last {now - last:.0f} s)'
        self._last_said[reason] = now
        self._count_at_last[reason] = total
        self.sink(f'{message}{suffix}')
