"""CARMEN log importer (``.clf``, ``.log``, either optionally gzip-compressed).

Line layouts (data README)::

    FLASER n r_1 .. r_n x y theta odom_x odom_y odom_theta ipc_timestamp hostname logger_ts
    ODOM x y theta tv rv accel ipc_timestamp hostname logger_ts

Two kinds of log are told apart automatically:

* **raw** logs (``mit-csail.clf``): the FLASER ``odom_*`` fields are the raw wheel
  odometry at the scan; they are merged in file order with any timestamped ``ODOM``
  lines into the odometry stream. There is no reference (use a ``reference_keyframes.txt``
  join, see :mod:`laser_odom.core.datasets.keyframes`).
* **GMapping-corrected** logs (``*-corrected.log.gz``), recognised by ``NEFF`` lines or by
  an ``ODOM`` line with stamp 0 right after a FLASER line. Per scan they hold
  ``ODOM raw_pose 0 0 0 t pippo t``, ``FLASER ... corrected_pose corrected_pose t pippo t``,
  ``ODOM corrected_pose 0 0 0 0 pippo 0`` and ``NEFF``. The FLASER pose is the reference;
  the ODOM line right after a FLASER is that corrected pose echoed (near the end of fr079
  it even carries a stray non-zero stamp), so it is never odometry; all other ODOM lines
  with a stamp form the raw odometry stream.

Stamps: the ``ipc_timestamp`` is used, not the logger's. It is the time the laser
message was made on the robot, the clock that ODOM lines and the derived keyframe joins
use, and it is strictly increasing on the real logs, whereas the logger stamp adds the
logging delay (on ``mit-csail.clf`` consecutive logger stamps of a 4.8 Hz laser come as
close as 20 ms). Should the ipc stamps still step back or repeat, the scans keep their
file order and are re-stamped by
:func:`~laser_odom.core.datasets.common.repair_scan_stamps`; odometry samples with such
stamps are dropped. Both are reported as warnings.

Beam angles and "no return" readings follow
:func:`~laser_odom.core.datasets.common.carmen_beam_geometry` and
:func:`~laser_odom.core.datasets.common.no_return_threshold`. Other line types (PARAM,
NEFF, SYNC, ...) are ignored.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import gzip
from pathlib import Path
import zlib

import numpy as np

from laser_odom.core.datasets.common import (
    carmen_beam_geometry, DatasetError, increasing_trajectory, LineIssues, LOGGER,
    make_scans, no_return_threshold, range_limit, repair_scan_stamps, seconds_to_ns)
from laser_odom.core.datasets.keyframes import load_keyframes
from laser_odom.core.trajectory import Dataset, Trajectory


def read_text_lines(path: Path | str) -> list[str]:
    """Return the lines of a plain or gzip-compressed text file (detected by magic bytes)."""
    try:
        with open(path, 'rb') as handle:
            data = handle.read()
        if data[:2] == b'\x1f\x8b':
            data = gzip.decompress(data)
    except OSError as exc:
        raise DatasetError(f'{path}: cannot read: {exc.strerror or exc}') from exc
    except (EOFError, zlib.error, gzip.BadGzipFile) as exc:
        raise DatasetError(f'{path}: corrupt gzip data: {exc}') from exc
    return data.decode('latin-1').splitlines()


@dataclass
class _CarmenLog:
    """What one pass over a CARMEN log collects before stamps are repaired."""

    ranges: list[np.ndarray] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)
    odom_fields: list[np.ndarray] = field(default_factory=list)
    scan_stamps: list[float] = field(default_factory=list)
    scan_lines: list[int] = field(default_factory=list)
    # 0-based position of each kept scan among all FLASER lines, malformed ones included
    scan_ordinals: list[int] = field(default_factory=list)
    flaser_count: int = 0
    # (pose x y theta, stamp s, file position) of ODOM lines and whether a FLASER preceded
    odom_lines: list[tuple[np.ndarray, float, int, bool]] = field(default_factory=list)
    has_neff: bool = False
    # laser line types this importer does not read (ROBOTLASER1, RAWLASER1, ...)
    unsupported: dict[str, int] = field(default_factory=dict)


def _parse_flaser(tokens: list[str]) -> tuple[np.ndarray, np.ndarray, float]:
    """Return ``(ranges, [x y theta odom_x odom_y odom_theta], ipc_stamp)`` of one line."""
    count = int(tokens[1])
    if count < 2:
        raise ValueError(f'beam count {count} < 2')
    if len(tokens) not in (count + 9, count + 11):
        raise ValueError(f'{count} beams need {count + 11} fields '
                         f'(or {count + 9} without host and logger stamp), got {len(tokens)}')
    values = np.array(tokens[2:count + 9], dtype=float)
    tail = values[count:]
    if not np.all(np.isfinite(tail)):
        raise ValueError('non-finite pose or stamp')
    if tail[6] <= 0.0:
        raise ValueError(f'no timestamp ({tokens[count + 8]})')
    return values[:count], tail[:6], float(tail[6])


def _parse_odom(tokens: list[str]) -> tuple[np.ndarray, float]:
    """Return ``([x y theta], ipc_stamp)`` of one ODOM line."""
    if len(tokens) < 8:
        raise ValueError(f'ODOM needs at least 8 fields, got {len(tokens)}')
    values = np.array(tokens[1:8], dtype=float)
    if not np.all(np.isfinite(values)):
        raise ValueError('non-finite value')
    return values[:3], float(values[6])


def _scan_log(lines: list[str], issues: LineIssues) -> _CarmenLog:
    """Parse FLASER and ODOM lines in one pass (malformed lines go to ``issues``)."""
    log = _CarmenLog()
    previous = ''
    for lineno, line in enumerate(lines, 1):
        tokens = line.split()
        if not tokens or tokens[0].startswith('#'):
            continue
        kind = tokens[0]
        try:
            if kind == 'FLASER':
                ranges, poses, stamp = _parse_flaser(tokens)
                log.ranges.append(ranges)
                log.poses.append(poses[:3])
                log.odom_fields.append(poses[3:])
                log.scan_stamps.append(stamp)
                log.scan_lines.append(lineno)
                log.scan_ordinals.append(log.flaser_count)
            elif kind == 'ODOM':
                pose, stamp = _parse_odom(tokens)
                log.odom_lines.append((pose, stamp, lineno, previous == 'FLASER'))
            elif kind == 'NEFF':
                log.has_neff = True
            elif 'LASER' in kind:
                log.unsupported[kind] = log.unsupported.get(kind, 0) + 1
        except (ValueError, IndexError) as exc:
            issues.add(lineno, f'malformed {kind} line: {exc}')
        log.flaser_count += kind == 'FLASER'
        previous = kind
    return log


def _odometry(log: _CarmenLog, corrected: bool, path: Path | str) -> Trajectory:
    """Return the raw wheel odometry stream in file order (see the module docstring)."""
    samples = [(line, stamp, pose) for pose, stamp, line, after_flaser in log.odom_lines
               if stamp > 0.0 and not (corrected and after_flaser)]
    if not corrected:
        samples += [(line, stamp, pose) for line, stamp, pose
                    in zip(log.scan_lines, log.scan_stamps, log.odom_fields)]
    if not samples:
        return Trajectory()
    samples.sort(key=lambda sample: sample[0])
    stamps = seconds_to_ns(np.array([sample[1] for sample in samples]))
    poses = np.array([sample[2] for sample in samples])
    return increasing_trajectory(stamps, poses, path, 'odometry')


def load_carmen(path: Path | str, name: str | None = None,
                keyframes: Path | str | None = None, strict: bool = False) -> Dataset:
    """Load a CARMEN log into a :class:`Dataset` (scans, raw odometry, reference).

    The reference is the per-scan corrected pose of a GMapping-corrected log, or else
    the ``keyframes`` join when given. Malformed lines are skipped with a logged warning
    (``strict`` raises instead); a log without any usable FLASER line raises
    :class:`DatasetError`.
    """
    path = Path(path)
    issues = LineIssues(path, strict)
    log = _scan_log(read_text_lines(path), issues)
    issues.log()
    if not log.ranges:
        others = ''.join(f'; {count} {kind} lines are not supported'
                         for kind, count in sorted(log.unsupported.items()))
        raise DatasetError(f'{path}: no laser scans (no valid FLASER line{others})')
    corrected = log.has_neff or any(after and stamp == 0.0
                                    for _, stamp, _, after in log.odom_lines)
    raw_stamps = seconds_to_ns(np.array(log.scan_stamps))
    stamps, changed = repair_scan_stamps(raw_stamps)
    if changed:
        LOGGER.warning('%s: re-stamped %d of %d scans whose ipc stamps were not increasing',
                       path, changed, len(stamps))
    threshold = no_return_threshold(np.concatenate(log.ranges))
    range_max = range_limit(threshold, np.concatenate(log.ranges))
    geometry = {count: carmen_beam_geometry(count) for count in {len(r) for r in log.ranges}}
    scans = make_scans(log.ranges, stamps, [geometry[len(r)] for r in log.ranges], range_max)
    if corrected:
        reference = increasing_trajectory(stamps, np.array(log.poses), path, 'reference')
    elif keyframes is not None:
        # keyframe indices count every FLASER line, including ones skipped as malformed
        full_raw = np.full(log.flaser_count, -1, dtype=np.int64)
        full_stamps = full_raw.copy()
        full_raw[log.scan_ordinals] = raw_stamps
        full_stamps[log.scan_ordinals] = stamps
        reference = load_keyframes(keyframes, full_raw, full_stamps, strict)
    else:
        reference = Trajectory()
    return Dataset(name=name or path.name, scans=scans,
                   odometry=_odometry(log, corrected, path), reference=reference)
