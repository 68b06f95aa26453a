"""The committed benchmark results read as documented figures, and a run held to them.

A result of ``laser_odom_bench --json`` over copies of each log (``--perturb N``: the
log as a bag delivers it, with 1 mm of range noise per copy) holds, besides its rows,
the ``spread`` of each run over the copies (:mod:`laser_odom.core.evaluation.spread`).
:func:`figure` gives the median copy's figures, which the documents quote, with the
worst copy's beside them; :func:`regression` holds a test run, which is one of the
copies, to the worst. A result of one run without copies (no ``spread``, as written
before) still reads, each figure being that run's. Rendering: :mod:`.figures`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
import statistics
from typing import Any, Mapping

ROOT = Path(__file__).resolve().parents[2]
FIGURES_JSON = ROOT / 'test' / 'figures' / 'benchmark.json'
"""The committed benchmark result (source tree only: it is not installed)."""

FAST_JSON = ROOT / 'test' / 'figures' / 'fast.json'
"""The committed benchmark result on the fast-robot logs (the ``fast`` block)."""

MATCHERS = ('icp', 'plicp', 'nicp', 'imls')
REAL_LOGS = (('fr079', 'fr079'), ('mit-csail', 'MIT-CSAIL'), ('intel', 'Intel'))
"""The real logs of the documented figures: dataset name and how the text names it."""

PRIOR = 'constant_velocity'
REFERENCES = ('scan', 'local_map')
TIMING_DATASETS = ('fr079', 'sim-office-1081')
"""Datasets whose median time per scan docs/benchmark.md quotes (360 and 1081 beams)."""

FAST_LOGS = ('fr079/5-fast', 'fr079/10-fast', 'intel-kf-fast')
"""The re-stamped fast-robot logs of the ``fast`` block (large steps 0.1 s apart)."""

FAST_MATCHERS = ('plicp', 'nicp', 'imls')
FAST_PRIORS = ('none', 'constant_velocity')


class FiguresError(ValueError):
    """The benchmark result lacks a figure, or a file lacks the place for it."""


def _read_result(path: Path, what: str) -> dict[str, Any]:
    """Read one ``laser_odom_bench --json`` result; anything amiss is a one-line error."""
    try:
        payload = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise FiguresError(f'no {what} {path}: run make figures') from None
    except (OSError, ValueError) as error:
        raise FiguresError(f'cannot read the {what} {path}: {error}') from error
    if not isinstance(payload, dict) or not isinstance(payload.get('rows'), list):
        raise FiguresError(f'{path} is not a laser_odom_bench --json result (no rows)')
    if 'spread' in payload and not isinstance(payload['spread'], list):
        raise FiguresError(f'{path}: its spread is not a list of runs')
    return payload


def load_figures(path: Path = FIGURES_JSON, fast: Path | None = None) -> dict[str, Any]:
    """Read the benchmark result, and with ``fast`` (:data:`FAST_JSON`) the fast-robot one.

    The fast-robot result goes under the key ``fast`` (the ``fast`` block needs it; the
    real-data tests do not). A missing file or key is a :class:`FiguresError`.
    """
    payload = _read_result(path, 'benchmark result')
    if fast is not None:
        payload = {**payload, 'fast': _read_result(fast, 'fast-robot benchmark result')}
    return payload


def _median(values: list[Any]) -> Any:
    """Return the median of a field over copies: numbers only, else the first value."""
    numbers = [v for v in values if isinstance(v, (int, float)) and not isinstance(v, bool)
               and math.isfinite(v)]
    if not numbers or any(isinstance(v, str) for v in values) or len(set(values)) == 1:
        return values[0]  # a count alike in every copy stays a whole number
    return statistics.median(numbers)


def figure(payload: Mapping[str, Any], dataset: str, matcher: str,
           reference: str = 'scan', prior: str = PRIOR) -> dict[str, Any]:
    """Return the figures of ``matcher`` on ``dataset``; say which is missing if it is.

    From a result with copies (``spread``): a row-like dict of the median copy (the
    spread's median of each summed-up figure, the median of the copies' rows for the
    rest, such as ``nees_100``) with ``copies`` and ``worst``, the worst copy's figures.
    From a single run: its row. Rows written before the ``reference`` key existed were
    matched scan to scan.
    """
    key = (dataset, matcher, prior, reference)
    rows = [row for row in payload['rows'] if (
        row.get('dataset'), row.get('matcher'), row.get('prior'),
        row.get('reference', 'scan')) == key]
    if not rows:
        raise FiguresError(f'the benchmark result has no {matcher} row on {dataset} '
                           f'({prior} prior, reference {reference}): run make figures')
    if 'spread' not in payload:
        return dict(rows[-1])
    spread = next((entry for entry in payload['spread'] if (
        entry.get('dataset'), entry.get('matcher'), entry.get('prior'),
        entry.get('reference')) == key), None)
    if spread is None:
        raise FiguresError(f'the benchmark result has no spread of {matcher} on {dataset} '
                           f'({prior} prior, reference {reference}): run make figures')
    median = {name: _median([row.get(name) for row in rows]) for name in rows[0]
              if name != 'copy'}
    return {**median, **spread['median'], 'copies': spread['copies'],
            'worst': dict(spread['worst'])}


def count(value: Any) -> str:
    """Return a count of steps as text: whole, or with a half (an even number of copies)."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return 'n/a'
    return str(int(value)) if float(value).is_integer() else f'{value:.1f}'


def spread_cell(row: Mapping[str, Any], name: str, decimals: int | None = None) -> str:
    """Return ``median [worst]`` of one figure (the median alone when they agree).

    ``decimals`` None formats a count of steps (:func:`count`).
    """
    median = row.get(name)
    worst = row.get('worst', {}).get(name, median)
    show = count if decimals is None else (
        lambda value: 'n/a' if value is None or math.isnan(value) else f'{value:.{decimals}f}')
    return show(median) if show(median) == show(worst) else f'{show(median)} [{show(worst)}]'


def copies_phrase(row: Mapping[str, Any]) -> str:
    """Return how a figure was measured: over copies with 1 mm range noise, or once."""
    copies = row.get('copies')
    return f', median of {copies} copies with 1 mm range noise' if copies else ''


def regression(row: Mapping[str, Any], documented: Mapping[str, Any],
               tolerance: float = 0.05) -> list[str]:
    """Return the figures of ``row`` more than ``tolerance`` worse than ``documented``.

    A documented result over copies (:func:`figure` of one with ``spread``) holds the
    run to its ``worst`` copy: a test runs one of those copies, and the median would
    fail it on the copies that drew the worse branch with the code unchanged. Without
    copies, to the run's own figures. Errors (mean RPE, ATE) may grow by the fraction;
    failed steps by the same fraction rounded up, so a log documented with 0 failures
    must keep 0.
    """
    bar = documented.get('worst', documented)
    worse = []
    for key in ('rpe_trans_mean', 'rpe_rot_mean', 'ate'):
        if not row[key] <= bar[key] * (1.0 + tolerance):
            worse.append(f'{key} {row[key]:.4f} > {bar[key]:.4f} + {tolerance:.0%}')
    failed = math.ceil(bar['failed'])  # a median of an even number of copies may be x.5
    allowed = failed + math.ceil(failed * tolerance)
    if row['failed'] > allowed:
        worse.append(f'failed {row["failed"]} > {allowed}')
    return worse
