"""Writing a tool's text output (TUM files, params files) without ever half-writing it.

A regular file is written to a temporary file beside it and moved into place with
``os.replace``, so a reader sees the old file or the new one, never a mix, and a
failed write leaves nothing behind. A path that is not a regular file - ``/dev/null``,
``/dev/stdout``, a named pipe - is written in place: replacing it would swap the device
for a plain file (and, run as root, break ``/dev/null`` for the whole machine).
"""

from __future__ import annotations

import os
from pathlib import Path
import secrets
import stat


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
