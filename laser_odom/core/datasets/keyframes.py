"""Join a derived ``reference_keyframes.txt`` to the scans of a log.

The file (data README) has one corrected keyframe per line, ``index stamp x y theta``,
where ``index`` is the 0-based scan (FLASER line or .mat row) it belongs to and ``stamp``
is that scan's logged time in seconds. The index is authoritative; the stamp is checked
against the scan's logged stamp so that a keyframe file paired with the wrong log is
refused instead of silently producing a wrong reference. The resulting reference poses
are stamped with the (repaired, strictly increasing) stamps of their scans, so the
benchmark can look them up by scan stamp.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from laser_odom.core import se2
from laser_odom.core.datasets.common import DatasetError, LineIssues, seconds_to_ns
from laser_odom.core.trajectory import Trajectory

KEYFRAMES_FILE = 'reference_keyframes.txt'
#: Largest accepted difference between a keyframe's stamp and its scan's logged stamp.
#: The joins were made within 20 ms; scans are >= 0.1 s apart, so a neighbouring scan
#: can never pass.
STAMP_TOLERANCE_S = 0.05


def keyframes_index_kind(path: Path | str) -> str | None:
    """Return the first column's name from a ``# columns:`` header line, if any.

    ``raw_scan_index`` marks a join to a CARMEN log's FLASER lines, ``mat_row_index`` one
    to the rows of a .mat file; the loader uses it to pick up only a matching file.
    """
    try:
        with open(path, encoding='latin-1') as handle:
            for line in handle:
                if not line.startswith('#'):
                    break
                if line.startswith('# columns:'):
                    words = line.split()
                    if len(words) > 2:
                        return words[2].split('(')[0]
    except OSError as exc:
        raise DatasetError(f'{path}: cannot read: {exc.strerror or exc}') from exc
    return None


def load_keyframes(path: Path | str, raw_stamps_ns: np.ndarray, stamps_ns: np.ndarray,
                   strict: bool = False) -> Trajectory:
    """Return the keyframe reference, stamped with the stamps of the scans it belongs to.

    ``raw_stamps_ns`` are the scans' logged stamps (for the stamp check) and ``stamps_ns``
    the repaired ones the scans carry, -1 for a scan that was skipped as malformed.
    Malformed lines, indices past the log's end and stamp mismatches are skipped with a
    warning (or raise when ``strict``); a file with no keyframe left is a
    :class:`DatasetError`.
    """
    issues = LineIssues(path, strict)
    try:
        with open(path, encoding='latin-1') as handle:
            lines = handle.read().splitlines()
    except OSError as exc:
        raise DatasetError(f'{path}: cannot read: {exc.strerror or exc}') from exc
    count = len(stamps_ns)
    tolerance_ns = STAMP_TOLERANCE_S * 1e9
    indices: list[int] = []
    poses: list[np.ndarray] = []
    for lineno, line in enumerate(lines, 1):
        tokens = line.split()
        if not tokens or tokens[0].startswith('#'):
            continue
        if len(tokens) < 5:
            issues.add(lineno, f'expected "index stamp x y theta", got {len(tokens)} fields')
            continue
        try:
            index = int(tokens[0])
            values = np.array(tokens[1:5], dtype=float)
        except ValueError as exc:
            issues.add(lineno, f'not a number: {exc}')
            continue
        if not np.all(np.isfinite(values)):
            issues.add(lineno, 'non-finite value')
        elif not 0 <= index < count:
            issues.add(lineno, f"scan index {index} outside the log's {count} scans")
        elif stamps_ns[index] < 0:
            issues.add(lineno, f'scan {index} was skipped as malformed')
        elif abs(int(seconds_to_ns(values[0])) - int(raw_stamps_ns[index])) > tolerance_ns:
            issues.add(lineno, f'stamp {tokens[1]} does not match scan {index} '
                               f'(logged at {raw_stamps_ns[index] * 1e-9:.6f} s): '
                               'keyframes of another log?')
        else:
            indices.append(index)
            poses.append(values[1:4])
    issues.log()
    if not indices:
        raise DatasetError(f'{path}: no keyframe matches the log')
    order = np.argsort(np.asarray(indices), kind='stable')
    index_array = np.asarray(indices)[order]
    unique = np.concatenate(([True], np.diff(index_array) > 0))
    if not unique.all():
        raise DatasetError(f'{path}: scan index {int(index_array[~unique][0])} '
                           'has more than one keyframe')
    pose_array = np.asarray(poses)[order]
    pose_array[:, 2] = se2.wrap_angle(pose_array[:, 2])
    return Trajectory(np.asarray(stamps_ns, dtype=np.int64)[index_array], pose_array)
