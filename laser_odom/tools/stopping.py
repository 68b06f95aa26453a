"""Ctrl-C that stops a tool between two scans, never inside a compiled kernel.

Python raises ``KeyboardInterrupt`` wherever the main thread happens to be; inside a
numba kernel that surfaces as ``SystemError: ... returned a result with an exception
set`` and a traceback instead of a clean stop. :func:`stop_between_scans` takes the
first Ctrl-C as a request: the tool calls :meth:`StopRequest.check` after each scan,
which raises :class:`Stopped` (a ``KeyboardInterrupt``) there, so the run ends with
what was done. A second Ctrl-C interrupts at once, as usual.
"""

from __future__ import annotations

from contextlib import contextmanager
import signal
import threading
from typing import Any, Iterator


class Stopped(KeyboardInterrupt):
    """The run was stopped by Ctrl-C between two scans."""


class StopRequest:
    """Whether Ctrl-C was pressed; :meth:`check` turns it into :class:`Stopped`."""

    def __init__(self) -> None:
        """Start with no request."""
        self.requested = False

    def check(self) -> None:
        """Raise :class:`Stopped` if Ctrl-C was pressed since the run began."""
        if self.requested:
            raise Stopped()


@contextmanager
def stop_between_scans() -> Iterator[StopRequest]:
    """Take the first SIGINT as a request to stop after the current scan (main thread only)."""
    request = StopRequest()
    if threading.current_thread() is not threading.main_thread():
        yield request
        return

    def on_sigint(signum: int, frame: Any) -> None:
        if request.requested:
            raise KeyboardInterrupt()
        request.requested = True

    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        yield request
    finally:
        signal.signal(signal.SIGINT, previous)
