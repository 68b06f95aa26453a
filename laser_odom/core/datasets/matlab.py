"""MATLAB ``.mat`` importer for the ``scan_intel.mat`` layout (``scipy.io.loadmat``).

Variables (data README): ``beam_data`` (N x n ranges in metres), ``timestamp`` (N logger
stamps in seconds), ``odom`` (N x 3 raw wheel odometry ``x y theta``, optional) and,
optionally, ``beam_start`` / ``beam_end`` / ``beam_n`` (the field of view, -pi/2 .. +pi/2,
and the beam count).

Beam angles: the README gives the Intel scans as 180 beams over 180 deg at 1 deg, so
``beam_start .. beam_end`` is read as a field of view with the CARMEN beam convention
(:func:`~laser_odom.core.datasets.common.carmen_beam_geometry`): 180 beams at -90 .. +89
deg, not ``linspace(-pi/2, pi/2, 180)`` (which would be 1.006 deg steps).

Stamps: ``timestamp`` is the logger's receive time and steps back 265 times on the real
file (by up to 0.9 s: single late stamps, the next ones are on time again). The rows are
in acquisition order (the odometry advances in row order), so the stamps are repaired
rather than the rows reordered: stamps off a longest non-decreasing run are re-estimated
by interpolation over the row index, then a 1 us minimum step is enforced
(:func:`~laser_odom.core.datasets.common.repair_scan_stamps`); odometry takes the
repaired row stamps. Rows with a non-finite stamp or odometry are skipped with a
warning (``path:row i: ...``).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import scipy.io

from laser_odom.core.datasets.common import (
    carmen_beam_geometry, DatasetError, increasing_trajectory, LineIssues, LOGGER,
    make_scans, no_return_threshold, range_limit, repair_scan_stamps, seconds_to_ns)
from laser_odom.core.datasets.keyframes import load_keyframes
from laser_odom.core.trajectory import Dataset, Trajectory


def _read_mat(path: Path) -> dict[str, Any]:
    """Return the variables of a MATLAB v4/v5 file, or raise :class:`DatasetError`."""
    try:
        return scipy.io.loadmat(str(path))
    except OSError as exc:
        raise DatasetError(f'{path}: cannot read: {exc.strerror or exc}') from exc
    except (ValueError, TypeError, NotImplementedError, KeyError, IndexError) as exc:
        raise DatasetError(f'{path}: not a readable MATLAB v4/v5 file: {exc}') from exc


def _scalar(variables: dict[str, Any], key: str, default: float) -> float:
    """Return a scalar variable (e.g. ``beam_start``), or ``default`` when absent."""
    if key not in variables:
        return default
    value = np.asarray(variables[key], dtype=float).reshape(-1)
    if value.size != 1 or not math.isfinite(value[0]):
        raise DatasetError(f'{key} must be one finite number')
    return float(value[0])


def _arrays(path: Path, variables: dict[str, Any]
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Return ``beam_data`` (N, n), ``timestamp`` (N,) and ``odom`` (N, 3) or None."""
    missing = [key for key in ('beam_data', 'timestamp') if key not in variables]
    if missing:
        raise DatasetError(f'{path}: no laser scans (missing variable {", ".join(missing)})')
    try:
        beams = np.asarray(variables['beam_data'], dtype=float)
        stamps = np.asarray(variables['timestamp'], dtype=float).reshape(-1)
        odom = variables.get('odom')
        odom = None if odom is None else np.asarray(odom, dtype=float)
    except (ValueError, TypeError) as exc:
        raise DatasetError(f'{path}: non-numeric scan data: {exc}') from exc
    if beams.ndim != 2 or beams.shape[0] == 0 or beams.shape[1] < 2:
        raise DatasetError(f'{path}: no laser scans (beam_data has shape {beams.shape})')
    rows = beams.shape[0]
    if stamps.shape[0] != rows:
        raise DatasetError(f'{path}: timestamp has {stamps.shape[0]} values '
                           f'for {rows} scans')
    if odom is not None and odom.shape != (rows, 3):
        raise DatasetError(f'{path}: odom has shape {odom.shape}, expected ({rows}, 3)')
    return beams, stamps, odom


def load_mat(path: Path | str, name: str | None = None,
             keyframes: Path | str | None = None, strict: bool = False) -> Dataset:
    """Load a ``scan_intel.mat``-style file into a :class:`Dataset`.

    ``keyframes`` (a ``reference_keyframes.txt`` of ``mat_row_index stamp x y theta``)
    becomes the reference, stamped with its rows' repaired stamps.
    """
    path = Path(path)
    variables = _read_mat(path)
    beams, seconds, odom = _arrays(path, variables)
    try:
        start = _scalar(variables, 'beam_start', -math.pi / 2)
        end = _scalar(variables, 'beam_end', math.pi / 2)
        declared = _scalar(variables, 'beam_n', beams.shape[1])
    except DatasetError as exc:
        raise DatasetError(f'{path}: {exc}') from exc
    if int(declared) != beams.shape[1] or not end > start:
        raise DatasetError(f'{path}: beam_n {declared:g} / field of view {start:g}..{end:g} '
                           f'do not fit beam_data with {beams.shape[1]} beams')
    good = np.isfinite(seconds) & (seconds >= 0.0)
    if odom is not None:
        good &= np.all(np.isfinite(odom), axis=1)
    issues = LineIssues(path, strict)
    for row in np.flatnonzero(~good):
        issues.add(f'row {row}', 'non-finite or negative timestamp, or non-finite odometry')
    issues.log()
    rows = np.flatnonzero(good)
    if rows.size == 0:
        raise DatasetError(f'{path}: no laser scans (no row with a valid timestamp)')
    raw_stamps = seconds_to_ns(np.where(good, seconds, -1.0))
    stamps, changed = repair_scan_stamps(raw_stamps[rows])
    if changed:
        LOGGER.warning('%s: re-stamped %d of %d scans whose stamps were not increasing',
                       path, changed, rows.size)
    threshold = no_return_threshold(beams[rows])
    range_max = range_limit(threshold, beams[rows])
    geometry = carmen_beam_geometry(beams.shape[1], start, end - start)
    scans = make_scans(list(beams[rows]), stamps, [geometry] * rows.size, range_max)
    odometry = Trajectory() if odom is None else increasing_trajectory(
        stamps, odom[rows], path, 'odometry')
    reference = Trajectory()
    if keyframes is not None:
        full_stamps = np.full(beams.shape[0], -1, dtype=np.int64)
        full_stamps[rows] = stamps
        reference = load_keyframes(keyframes, raw_stamps, full_stamps, strict)
    return Dataset(name=name or path.name, scans=scans, odometry=odometry,
                   reference=reference)
