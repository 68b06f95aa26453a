"""``--quiet`` for every tool: no warnings, no progress; errors still reach stderr."""

from __future__ import annotations

from contextlib import contextmanager
import logging
import os
import sys
from typing import Iterator
import warnings

READER_LEFT_STATUS = 1
"""Exit status when the reader of the output left early (``tool | head``): not all of the
output was delivered, as with Python's own handling of a broken pipe."""


@contextmanager
def warnings_silenced(quiet: bool) -> Iterator[None]:
    """Silence every warning inside the block when ``quiet``; errors still reach stderr.

    Warnings reach stderr two ways, and both are closed here: logged ones (the params
    file's unknown names, the dataset readers' skipped lines and re-stamped scans, the
    pipeline's throttled event
    messages when its :class:`~laser_odom.core.events.EventLog` has the default sink,
    the ``laser_odom`` logger; with no handler configured Python's last-resort handler
    prints them) and Python ``warnings``, numpy's RuntimeWarnings included. (The
    benchmark's own pipelines already send their event messages to a no-op sink.)
    Logged errors (level ERROR and above) and the tool's own error lines still show.
    """
    if not quiet:
        yield
        return
    previous = logging.root.manager.disable
    logging.disable(logging.WARNING)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            yield
    finally:
        logging.disable(previous)


@contextmanager
def reader_may_leave() -> Iterator[None]:
    """Stop quietly when the reader of standard output leaves (``tool | head -1``).

    A closed pipe is not the tool's failure and gets no traceback: standard output is
    pointed at the null device, so that the interpreter's final flush does not fail
    again, and the tool exits with :data:`READER_LEFT_STATUS`.
    """
    try:
        yield
    except BrokenPipeError:
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, sys.stdout.fileno())
        raise SystemExit(READER_LEFT_STATUS)
