"""TUM trajectory files: one pose per line, ``t x y z qx qy qz qw``.

The format of the TUM RGB-D benchmark (Sturm et al., IROS 2012), read by evo and most
trajectory tools. Planar poses are written with ``z = 0`` and a yaw-only quaternion;
stamps are seconds with 9 decimals and are converted to and from integer
nanoseconds exactly (decimal arithmetic, no float rounding).
"""

from __future__ import annotations

from decimal import Decimal, InvalidOperation
import math
from pathlib import Path

import numpy as np

from laser_odom.core import se2
from laser_odom.core.trajectory import Trajectory
from laser_odom.io.errors import OutputExistsError
from laser_odom.io.text_output import write_text_atomically

HEADER = '# timestamp x y z qx qy qz qw'
FIELDS = 8
NS_PER_S = 10 ** 9


class TumFormatError(ValueError):
    """A TUM file is malformed; the message names the file and the line."""


def format_stamp(stamp_ns: int) -> str:
    """Return ``stamp_ns`` as seconds with exactly 9 decimals (``-`` for negative stamps)."""
    sign = '-' if stamp_ns < 0 else ''
    sec, nsec = divmod(abs(int(stamp_ns)), NS_PER_S)
    return f'{sign}{sec}.{nsec:09d}'


def parse_stamp(text: str) -> int:
    """Return the integer nanoseconds of a decimal seconds string (rounded to 1 ns)."""
    value = Decimal(text) * NS_PER_S
    if not value.is_finite():
        raise InvalidOperation(text)
    return int(value.to_integral_value())


def write_tum(path: str | Path, trajectory: Trajectory, overwrite: bool = True) -> None:
    """Write ``trajectory`` to ``path`` atomically (:func:`write_text_atomically`).

    With ``overwrite=False`` an existing ``path`` raises :class:`OutputExistsError`.
    A reader never sees a half-written file, and a failed write leaves nothing behind.
    """
    path = Path(path)
    if not overwrite and (path.exists() or path.is_symlink()):
        raise OutputExistsError(f'{path} exists already; not overwriting it')
    lines = [HEADER]
    poses = trajectory.poses
    half = 0.5 * poses[:, 2]
    qz, qw = np.sin(half), np.cos(half)
    for i, stamp in enumerate(trajectory.stamps_ns):
        lines.append(f'{format_stamp(int(stamp))} {poses[i, 0]:.9f} {poses[i, 1]:.9f} '
                     f'0 0 0 {qz[i]:.12f} {qw[i]:.12f}')
    write_text_atomically(path, '\n'.join(lines) + '\n', encoding='ascii')


def _parse_line(line: str, where: str) -> tuple[int, np.ndarray]:
    """Return the stamp and the planar pose of one TUM line."""
    parts = line.split()
    if len(parts) != FIELDS:
        raise TumFormatError(f'{where}: expected {FIELDS} fields '
                             f'(t x y z qx qy qz qw), found {len(parts)}')
    try:
        stamp = parse_stamp(parts[0])
        x, y, _z, qx, qy, qz, qw = (float(v) for v in parts[1:])
    except (ValueError, InvalidOperation):
        raise TumFormatError(f'{where}: not a number in {line.strip()!r}') from None
    values = (x, y, qx, qy, qz, qw)
    if not all(math.isfinite(v) for v in values):
        raise TumFormatError(f'{where}: non-finite value')
    if math.hypot(math.hypot(qx, qy), math.hypot(qz, qw)) < 1e-6:
        raise TumFormatError(f'{where}: zero quaternion')
    return stamp, np.array([x, y, se2.quaternion_to_yaw(qx, qy, qz, qw)])


def read_tum(path: str | Path) -> Trajectory:
    """Read a TUM file into a :class:`Trajectory` (yaw from the quaternion).

    Blank lines and ``#`` comments are skipped; a malformed line or a stamp that does
    not increase raises :class:`TumFormatError` naming the line number.
    """
    path = Path(path)
    stamps: list[int] = []
    poses: list[np.ndarray] = []
    with path.open('r', encoding='utf-8', errors='replace') as handle:
        for number, line in enumerate(handle, start=1):
            text = line.strip()
            if not text or text.startswith('#'):
                continue
            where = f'{path}:{number}'
            stamp, pose = _parse_line(text, where)
            if stamps and stamp <= stamps[-1]:
                raise TumFormatError(f'{where}: stamp {format_stamp(stamp)} is not after the '
                                     f'one before it ({format_stamp(stamps[-1])})')
            stamps.append(stamp)
            poses.append(pose)
    if not stamps:
        return Trajectory()
    return Trajectory(np.array(stamps, dtype=np.int64), np.vstack(poses))
