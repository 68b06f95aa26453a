"""``--quiet`` for every tool: no warnings, no progress; errors still reach stderr."""

from __future__ import annotations

from contextlib import contextmanager
import logging
from typing import Iterator
import warnings


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
