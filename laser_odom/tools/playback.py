"""Publishing on the wall clock: recorded messages at a rate, like ``ros2 bag play --rate``.

Shared by ``laser_odom_bench --live`` (simulated scans at the sensor rate) and
``laser_odom_replay --live --rate`` (a bag's scans and prior messages at ``R`` times
their recorded rate). Nothing waits for an answer: an action that comes due while
the previous one is still running runs as soon as it can, and the largest such delay
is reported so that a publisher too slow for the rate is not mistaken for a node
that is too slow.
"""

from __future__ import annotations

import time
from typing import Callable, Iterable

MAX_GAP_NS = 5_000_000_000
"""A longer pause between two recorded stamps is played as this long (a bag that was
paused, or whose clock jumped); stamps that go back are played at once."""


class RecordedClock:
    """Maps recorded stamps, in the order they are played, to wall-clock offsets [s].

    The first stamp plays at offset 0; each later one after the recorded gap to its
    predecessor divided by ``rate`` (gaps clipped to ``0 .. max_gap_ns``).
    """

    def __init__(self, rate: float, max_gap_ns: int = MAX_GAP_NS) -> None:
        """Play ``rate`` times faster than recorded (``rate > 0``)."""
        if not rate > 0.0:
            raise ValueError(f'rate must be > 0, not {rate}')
        self.rate = float(rate)
        self.max_gap_ns = int(max_gap_ns)
        self._last_ns: int | None = None
        self._offset = 0.0

    def offset(self, stamp_ns: int) -> float:
        """Return the offset [s] from the start at which ``stamp_ns`` is played."""
        if self._last_ns is not None:
            gap = min(max(int(stamp_ns) - self._last_ns, 0), self.max_gap_ns)
            self._offset += gap * 1e-9 / self.rate
        self._last_ns = int(stamp_ns)
        return self._offset


def play(events: Iterable[tuple[float, Callable[[], None]]],
         wait: Callable[[float], None] = time.sleep,
         clock: Callable[[], float] = time.monotonic) -> float:
    """Run each ``(offset, action)`` at ``offset`` seconds after the first event's time.

    ``events`` come in order of offset and may be a lazy generator: an event is taken
    (and its message built) before waiting for its time, so building does not delay
    the publishing. ``wait(seconds)`` passes the time until the next event (sleeping,
    or spinning an executor). Return the largest delay [s] by which an action started
    after its time (0 when the publisher kept up).
    """
    start: float | None = None
    late = 0.0
    for offset, action in events:
        now = clock()
        if start is None:
            start = now - offset
        delay = start + offset - now
        if delay > 0.0:
            wait(delay)
        else:
            late = max(late, -delay)
        action()
    return late
