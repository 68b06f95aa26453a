"""Writing a tool's text output (TUM files, params files) without ever half-writing it.

A regular file is written to a temporary file beside it and moved into place with
``os.replace``, so a reader sees the old file or the new one, never a mix, and a
failed write leaves nothing behind. A path that is not a regular file - ``/dev/null``,
``/dev/stdout``, a named pipe - is written in place: replacing it would swap the device
for a plain file (and, run as root, break ``/dev/null`` for the whole machine).
Printed output whose reader leaves early (``tool | head``) ends quietly
(:func:`reader_may_leave`).
"""

from __future__ import annotations

from contextlib import contextmanager
import os
from pathlib import Path
import secrets
import stat
import sys
from typing import Iterator

READER_LEFT_STATUS = 1
"""Exit status when the reader of the output left early (``tool | head``): not all of the
output was delivered, as with Python's own handling of a broken pipe."""


def is_special_file(path: Path) -> bool:
    """Tell whether ``path`` exists and is a device, pipe or socket, not a regular file."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return not stat.S_ISREG(mode) and not stat.S_ISDIR(mode)


def write_text_atomically(path: str | Path, text: str, encoding: str = 'utf-8') -> None:
    """Write ``text`` to ``path``: atomically for a regular file, in place for a device."""
    path = Path(path)
    if is_special_file(path):
        with path.open('w', encoding=encoding) as handle:
            handle.write(text)
        return
    tmp = path.with_name(f'.{path.name}.{os.getpid()}.{secrets.token_hex(4)}.partial')
    try:
        with tmp.open('x', encoding=encoding) as handle:
            handle.write(text)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextmanager
def reader_may_leave(status: int = READER_LEFT_STATUS) -> Iterator[None]:
    """Stop quietly when the reader of standard output leaves (``tool | head -1``).

    A closed pipe is not the program's failure and gets no traceback: standard output
    is pointed at the null device, so that the interpreter's final flush does not fail
    again, and the program exits with ``status``.
    """
    try:
        yield
    except BrokenPipeError:
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, sys.stdout.fileno())
        raise SystemExit(status)
