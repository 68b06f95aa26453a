"""The benchmark's tables: fixed-width columns and the machine they were measured on."""

from __future__ import annotations

import math
import os
from pathlib import Path
import platform
from typing import Sequence

import numpy as np

from laser_odom.core.configuration.pipeline import GlobalSearchConfig
from laser_odom.core.evaluation.benchmark import BenchRow, WHEEL_ODOMETRY
from laser_odom.core.evaluation.search_timing import SearchTimingRow
from laser_odom.core.evaluation.spread import SpreadRow
from laser_odom.io.bag_dataset import BAG_GROUND_TRUTH

COLUMNS = [
    ('dataset', 25, None, 'dataset'), ('matcher', 14, None, 'matcher'),
    ('prior', 17, None, 'prior'), ('deskew', 6, None, 'deskew'),
    ('reference', 9, None, 'reference'), ('beams', 5, None, 'beams'),
    ('steps', 5, None, 'steps'),
    ('rpe_trans_mean', 9, 4, 'RPEt mean'), ('rpe_trans_rms', 8, 4, 'RPEt RMS'),
    ('rpe_rot_mean', 9, 3, 'RPEr mean'), ('rpe_rot_rms', 8, 3, 'RPEr RMS'),
    ('ate', 7, 3, 'ATE'), ('drift_trans', 7, 2, 'drift%'), ('drift_rot', 7, 3, 'deg/m'),
    ('failed', 6, None, 'failed'), ('silent', 6, None, 'silent'),
    ('median_ms', 7, 2, 'med ms'), ('p95_ms', 7, 2, 'p95 ms'),
]
"""Table columns: row field, width, decimals (None: as is), title."""


def cpu_name() -> str:
    """Return the CPU model name (Linux), or the platform's processor string."""
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or 'unknown CPU'


def machine_line(live: bool = False) -> str:
    """Return the line that says what machine the timings come from (and how taken)."""
    how = ('timings: a node process and this one, over DDS' if live else
           'timings: median/p95 ms per scan after a warm-up, whole per-scan work in one '
           'process')
    return (f'# {cpu_name()}, {os.cpu_count()} cores; Python {platform.python_version()}, '
            f'numpy {np.__version__}; {how}')


def provenance() -> dict[str, object]:
    """Return when and with what a benchmark ran, for its ``--json`` (figures are traced).

    The date (UTC), the machine line, and the versions of Python, numpy, scipy and
    numba: a documented figure can be reproduced, or its drift explained.
    """
    import datetime

    import numba
    import scipy
    return {'date': datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC'),
            'machine': machine_line().split(';')[0].lstrip('# '),
            'versions': {'python': platform.python_version(), 'numpy': np.__version__,
                         'scipy': scipy.__version__, 'numba': numba.__version__}}


def _cell(value: object, width: int, decimals: int | None) -> str:
    """Format one table cell: text left-aligned, numbers right-aligned, n/a for no value."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return f'{"n/a":>{width}}'
    if isinstance(value, str):
        return f'{value:<{width}}'
    if decimals is None:
        return f'{value:>{width}}'
    return f'{value:>{width}.{decimals}f}'


def _columns(rows: Sequence, columns: list, text_columns: int) -> list[str]:
    """Return the header and one line per row (``as_dict``) of a fixed-width table."""
    lines = [' '.join(_cell(title, width, None) if i < text_columns else f'{title:>{width}}'
                      for i, (_, width, _, title) in enumerate(columns))]
    for row in rows:
        values = row.as_dict()
        lines.append(' '.join(_cell(values[key], width, decimals)
                              for key, width, decimals, _ in columns))
    return lines


def format_table(rows: Sequence[BenchRow]) -> str:
    """Return the rows as a fixed-width text table with units in the legend."""
    unscored = sorted({row.dataset for row in rows if row.failed is None
                       and row.matcher != WHEEL_ODOMETRY})
    lengths = sorted({row.drift_length for row in rows if math.isfinite(row.drift_length)})
    return '\n'.join(_columns(rows, COLUMNS, 5) + [
        '# RPE between consecutive reference poses (t: m, r: deg); ATE [m] after SE(2) '
        'alignment; drift: KITTI-style error per path length over segments of '
        f'{"/".join(f"{length:g}" for length in lengths) or "50"} m of path (% and deg/m); '
        'failed: RPE > 0.5 m or > 10 deg; silent: failed steps that the '
        'published step covariance did not cover (NEES e^T (S + 2R)^-1 e above 16.27, the '
        '99.9 % bound; the others were announced); deskew: the pipeline setting '
        '(auto: on when the scans have a time_increment); reference: matched against the '
        'previous scan or the local map'] + (
        [f'# n/a: no reference for {", ".join(unscored)} (--bag without --reference or '
         f'{BAG_GROUND_TRUTH}): timed only'] if unscored else []))


SPREAD_COLUMNS = [
    ('ate', 13, 3, 'ATE m'), ('drift_trans', 13, 2, 'drift %'),
    ('failed', 9, 0, 'failed'), ('silent', 9, 0, 'silent'),
    ('rpe_trans_mean', 15, 4, 'RPEt mean'), ('nees_integrated', 13, 2, 'NEES int'),
    ('median_ms', 11, 2, 'med ms'),
]
"""Figures of the spread table: field, width, decimals, title."""

SPREAD_KEYS = [('dataset', 25), ('matcher', 8), ('prior', 17), ('reference', 9),
               ('copies', 6)]
"""The spread table's key columns: field, width."""


def format_spread_table(rows: Sequence[SpreadRow]) -> str:
    """Return the median [worst] of each figure over the copies of every run."""
    header = ' '.join([f'{title:<{width}}' for title, width in SPREAD_KEYS]
                      + [f'{title:>{width}}' for _, width, _, title in SPREAD_COLUMNS])
    lines = [header]
    for row in rows:
        values = row.as_dict()
        lines.append(' '.join(
            [f'{values[key]!s:<{width}}' for key, width in SPREAD_KEYS]
            + [f'{row.cell(name, decimals):>{width}}'
               for name, width, decimals, _ in SPREAD_COLUMNS]))
    copies = sorted({row.copies for row in rows})
    return '\n'.join(lines + [
        f'# median [worst] over {"/".join(map(str, copies))} copies of each dataset, as '
        'received (float32 LaserScan), with 1 mm of Gaussian noise on every range (one '
        'value: all copies alike); figures as in the table of rows (NEES int: integrated '
        'pose, about 3 when honest)'])


NEES_COLUMNS = [
    ('dataset', 25, None, 'dataset'), ('matcher', 14, None, 'matcher'),
    ('prior', 17, None, 'prior'), ('deskew', 6, None, 'deskew'),
    ('reference', 9, None, 'reference'), ('steps', 5, None, 'steps'),
    ('reference_noise_m', 6, 3, 'ref m'), ('reference_noise_deg', 7, 2, 'ref deg'),
    ('nees_1', 7, 2, 'NEES 1'), ('nees_10', 8, 2, 'NEES 10'), ('nees_100', 8, 2, 'NEES 100'),
    ('nees_integrated', 8, 2, 'NEES int'),
]
"""Columns of the consistency table (``--nees``): field, width, decimals, title."""


def format_nees_table(rows: Sequence[BenchRow]) -> str:
    """Return the rows' NEES as a second fixed-width table (the wheel odometry row has none)."""
    scored = [row for row in rows if row.matcher != WHEEL_ODOMETRY]
    return '\n'.join(
        ['# consistency of the published covariance: mean NEES = e^T (P + 2R)^-1 e, about 3 '
         'when honest (3 dof; above: too confident, below: too pessimistic)']
        + _columns(scored, NEES_COLUMNS, 5)
        + ['# NEES 1/10/100: relative pose over windows of at least 1, 10, 100 steps from a '
           'referenced scan to a referenced scan (every few scans on keyframe references); '
           'NEES int: the published pose relative to the first referenced scan; R = '
           'diag(ref m^2, ref m^2, (ref deg * pi / 180)^2): the noise of each reference '
           'pose (0: '
           'simulated truth)'])


SEARCH_COLUMNS = [
    ('dataset', 25, None, 'dataset'), ('beams', 5, None, 'beams'),
    ('searches', 8, None, 'searches'), ('median_ms', 7, 2, 'med ms'),
    ('p95_ms', 7, 2, 'p95 ms'), ('grid_ms', 7, 2, 'grid ms'), ('tree_ms', 7, 2, 'tree ms'),
    ('nodes', 7, None, 'nodes'), ('exhaustive', 10, 2, 'exhaustive'),
]
"""Columns of the global-search table: field, width, decimals, title."""


def format_search_table(rows: Sequence[SearchTimingRow]) -> str:
    """Return the global-search timings as a fixed-width table."""
    window = GlobalSearchConfig()
    return '\n'.join(
        [f'# global search alone, default window +-{window.global_search_linear:g} m, '
         f'+-{math.degrees(window.global_search_angular):.0f} deg at '
         f'{window.global_search_resolution:g} m; consecutive scans, zero guess']
        + _columns(rows, SEARCH_COLUMNS, 1)
        + ['# med/p95 ms: whole search; grid: rasterise and bound the reference; tree: '
           'score the branch-and-bound nodes (median count); exhaustive: share of '
           'searches below the node cap'])
