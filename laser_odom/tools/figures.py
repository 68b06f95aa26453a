"""Documented figures, rendered from the committed benchmark result (``make docs``).

Every block between ``<!-- figures:NAME:begin -->`` and ``<!-- figures:NAME:end -->``
in the pages of ``docs/`` (the real-log and local-map tables and the per-scan times in
``docs/benchmark.md``, the NEES in ``docs/node.md``), and the block "Measured with these
values" in each ``config/<matcher>.yaml``, are written from ``test/figures/benchmark.json``
- the ``--json`` of one ``laser_odom_bench`` run (``make figures``), which records its
date, machine and library versions. A block may sit in any of those pages
(:data:`BLOCKS` renders it wherever its markers are), but in exactly one. The README
holds no figures: it is a guide, and says which option when in words. Nothing is typed
by hand: ``test_docs`` fails when the files and the JSON disagree, and
``test_real_data`` fails when the code falls more than 5 % behind a committed figure.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
import sys
from typing import Any, Mapping, Sequence

from laser_odom.io.text_output import write_text_atomically

ROOT = Path(__file__).resolve().parents[2]
FIGURES_JSON = ROOT / 'test' / 'figures' / 'benchmark.json'
"""The committed benchmark result (source tree only: it is not installed)."""

MATCHERS = ('icp', 'plicp', 'nicp', 'imls')
REAL_LOGS = (('fr079', 'fr079'), ('mit-csail', 'MIT-CSAIL'), ('intel', 'Intel'))
"""The real logs of the documented figures: dataset name and how the text names it."""

PRIOR = 'constant_velocity'
TIMING_DATASETS = ('fr079', 'sim-office-1081')
"""Datasets whose median time per scan docs/benchmark.md quotes (360 and 1081 beams)."""

DOCUMENTS = ('docs/benchmark.md', 'docs/node.md')
"""Documents (relative to the source tree) whose figure blocks ``make docs`` renders."""

CONFIG_MARKERS = ('# figures:begin', '# figures:end')


def markers(block: str) -> tuple[str, str]:
    """Return the begin and end marker lines of a figure block in Markdown."""
    return f'<!-- figures:{block}:begin -->', f'<!-- figures:{block}:end -->'


class FiguresError(ValueError):
    """The benchmark result lacks a figure, or a file lacks the place for it."""


def load_figures(path: Path = FIGURES_JSON) -> dict[str, Any]:
    """Read the benchmark result; a missing file or key is a :class:`FiguresError`."""
    try:
        payload = json.loads(Path(path).read_text())
    except (OSError, ValueError) as error:
        raise FiguresError(f'cannot read the benchmark result {path}: {error}') from error
    if not isinstance(payload, dict) or not isinstance(payload.get('rows'), list):
        raise FiguresError(f'{path} is not a laser_odom_bench --json result (no rows)')
    return payload


def figure_rows(payload: Mapping[str, Any], reference: str = 'scan'
                ) -> dict[tuple[str, str], dict[str, Any]]:
    """Return the constant-velocity rows matched against ``reference`` by (dataset, matcher).

    Rows written before the ``reference`` key existed were matched scan to scan.
    """
    return {(row['dataset'], row['matcher']): row for row in payload['rows']
            if row.get('prior') == PRIOR and row.get('reference', 'scan') == reference}


def figure(payload: Mapping[str, Any], dataset: str, matcher: str,
           reference: str = 'scan') -> dict[str, Any]:
    """Return the row of ``matcher`` on ``dataset``; say which is missing if it is."""
    row = figure_rows(payload, reference).get((dataset, matcher))
    if row is None:
        raise FiguresError(f'the benchmark result has no {matcher} row on {dataset} '
                           f'({PRIOR} prior, reference {reference}): run make figures')
    return row


def real_log_table(payload: Mapping[str, Any]) -> str:
    """Markdown table: mean RPE (m / deg), ATE (m) and failed steps per matcher and log."""
    beams = {name: figure(payload, name, MATCHERS[0])['beams'] for name, _ in REAL_LOGS}
    heading = ' | '.join(f'{name} ({beams[name]} beams)' for name, _ in REAL_LOGS)
    lines = [f'| matcher | {heading} |',
             '|---|' + '---|' * len(REAL_LOGS)]
    for matcher in MATCHERS:
        cells = []
        for name, _ in REAL_LOGS:
            row = figure(payload, name, matcher)
            cells.append(f'{row["rpe_trans_mean"]:.3f} / {row["rpe_rot_mean"]:.2f} / '
                         f'{row["ate"]:.2f} / {row["failed"]}')
        lines.append(f'| `{matcher}` | ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines) + '\n'


def speed_sentence(payload: Mapping[str, Any]) -> str:
    """Return the per-scan times: fr079 (360 beams) and the 1081-beam simulated office."""
    def times(dataset: str) -> list[str]:
        return [f'{figure(payload, dataset, m)["median_ms"]:.1f}' for m in MATCHERS]

    at_360, at_1081 = (times(name) for name in TIMING_DATASETS)
    machine = payload.get('machine', 'unknown machine').split(';')[0]  # older: whole line
    named = ', '.join(f'`{m}` {t} ms' for m, t in zip(MATCHERS, at_360))
    return (f'Median time per scan on fr079 (360 beams, constant-velocity prior, '
            f'`laser_odom_bench`, {machine}, {payload.get("date", "undated")}): {named}; at '
            f'1081 beams (simulated office) {", ".join(at_1081[:-1])} and {at_1081[-1]} ms.\n')


def nees_sentence(payload: Mapping[str, Any]) -> str:
    """Return the real-log NEES over 100 steps and whole logs, every matcher."""
    rows = [figure(payload, name, m) for name, _ in REAL_LOGS for m in MATCHERS]

    def spread(key: str) -> str:
        values = [row[key] for row in rows]
        return f'{min(values):.0f}-{max(values):.0f}'

    noise = rows[0]
    return (f'On the real logs (`laser_odom_bench --nees`, {payload.get("date", "undated")}, '
            f'{100 * noise["reference_noise_m"]:.0f} cm / {noise["reference_noise_deg"]:.0f} '
            f'deg of reference noise allowed for) the NEES is {spread("nees_100")} over 100 '
            f'steps and {spread("nees_integrated")} over a whole log.\n')


def config_block(payload: Mapping[str, Any], matcher: str) -> str:
    """Comment lines for ``config/<matcher>.yaml``: the matcher's figures on each log."""
    lines = ['# Measured with these values by laser_odom_bench (constant-velocity prior, '
             f'{payload.get("date", "undated")}):',
             '# mean RPE between consecutive reference poses, ATE after SE(2) alignment, '
             'failed steps',
             '# (RPE > 0.5 m or 10 deg) and median time per scan:']
    for name, label in REAL_LOGS:
        row = figure(payload, name, matcher)
        lines.append(f'#   {label:<10} {row["rpe_trans_mean"]:.4f} m  '
                     f'{row["rpe_rot_mean"]:.3f} deg  ATE {row["ate"]:.2f} m  '
                     f'{row["failed"]} failed  {row["median_ms"]:4.1f} ms ({row["beams"]} beams)')
    return '\n'.join(lines) + '\n'


def replace_between(text: str, markers: tuple[str, str], body: str, where: str) -> str:
    """Return ``text`` with what lies between the two marker lines replaced by ``body``."""
    begin, end = markers
    if text.count(begin) != 1 or text.count(end) != 1 or text.index(begin) > text.index(end):
        raise FiguresError(f'{where} needs one {begin!r} line and one {end!r} line after it')
    head, rest = text.split(begin, 1)
    tail = rest.split(end, 1)[1]
    return f'{head}{begin}\n{body}{end}{tail}'


def map_table(payload: Mapping[str, Any]) -> str:
    """Markdown table: scan to scan -> local map, per matcher and log, and the time cost.

    Each cell holds the drift over 50 m of path (% of the path) and the ATE (m) in
    both modes; the last column the median time per scan on fr079 in both.
    """
    lines = ['| matcher | ' + ' | '.join(f'{name}: drift %, ATE m' for name, _ in REAL_LOGS)
             + f' | {TIMING_DATASETS[0]}: ms per scan |',
             '|---|' + '---|' * (len(REAL_LOGS) + 1)]
    for matcher in MATCHERS:
        cells = []
        for name, _ in REAL_LOGS:
            scan, mapped = (figure(payload, name, matcher, reference)
                            for reference in ('scan', 'local_map'))
            cells.append(f'{scan["drift_trans"]:.2f} -> {mapped["drift_trans"]:.2f}, '
                         f'{scan["ate"]:.2f} -> {mapped["ate"]:.2f}')
        scan, mapped = (figure(payload, TIMING_DATASETS[0], matcher, reference)
                        for reference in ('scan', 'local_map'))
        cells.append(f'{scan["median_ms"]:.1f} -> {mapped["median_ms"]:.1f}')
        lines.append(f'| `{matcher}` | ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines) + '\n'


BLOCKS = {'table': real_log_table, 'speed': speed_sentence, 'nees': nees_sentence,
          'map': map_table}
"""Every figure block, by name: its renderer from the benchmark result."""


def blocks_in(text: str) -> list[str]:
    """Return the names of the figure blocks whose markers a document holds."""
    return [name for name in BLOCKS if markers(name)[0] in text]


def rendered_text(text: str, payload: Mapping[str, Any], where: str = 'docs') -> str:
    """Return a document with every figure block it holds rendered from ``payload``."""
    for name in blocks_in(text):
        text = replace_between(text, markers(name), BLOCKS[name](payload), where)
    return text


def rendered_config(text: str, payload: Mapping[str, Any], matcher: str) -> str:
    """Return a matcher's params-file text with its figures rendered from ``payload``."""
    return replace_between(text, CONFIG_MARKERS, config_block(payload, matcher),
                           f'config/{matcher}.yaml')


def regression(row: Mapping[str, Any], documented: Mapping[str, Any],
               tolerance: float = 0.05) -> list[str]:
    """Return the figures of ``row`` more than ``tolerance`` worse than ``documented``.

    Errors (mean RPE, ATE) may grow by the fraction; failed steps by the same fraction
    rounded up, so a log documented with 0 failures must keep 0.
    """
    worse = []
    for key in ('rpe_trans_mean', 'rpe_rot_mean', 'ate'):
        if not row[key] <= documented[key] * (1.0 + tolerance):
            worse.append(f'{key} {row[key]:.4f} > {documented[key]:.4f} + {tolerance:.0%}')
    allowed = documented['failed'] + math.ceil(documented['failed'] * tolerance)
    if row['failed'] > allowed:
        worse.append(f'failed {row["failed"]} > {allowed}')
    return worse


def main(argv: Sequence[str] | None = None) -> int:
    """Rewrite the documented figures from the committed benchmark result."""
    parser = argparse.ArgumentParser(prog='python -m laser_odom.tools.figures',
                                     description=__doc__.splitlines()[0])
    parser.add_argument('--json', type=Path, default=FIGURES_JSON,
                        help='benchmark result (default: test/figures/benchmark.json)')
    parser.add_argument('--root', type=Path, default=ROOT,
                        help='source tree whose docs/ and config/ to update '
                        "(default: this package's)")
    args = parser.parse_args(argv)
    try:
        payload = load_figures(args.json)
        updated = {}
        placed: dict[str, str] = {}
        for relative in DOCUMENTS:
            path = args.root / relative
            text = path.read_text()
            for name in blocks_in(text):
                if name in placed:
                    raise FiguresError(f'figure block {name} is in {placed[name]} and in '
                                       f'{relative}: keep it in one')
                placed[name] = relative
            updated[path] = rendered_text(text, payload, relative)
        missing = sorted(set(BLOCKS) - set(placed))
        if missing:
            raise FiguresError(f'no document holds the figure block {missing[0]} (markers '
                               f'{markers(missing[0])[0]} ...)')
        for matcher in MATCHERS:
            path = args.root / 'config' / f'{matcher}.yaml'
            updated[path] = rendered_config(path.read_text(), payload, matcher)
    except (FiguresError, OSError) as error:
        print(f'figures: error: {error}', file=sys.stderr)
        return 2
    for path, text in updated.items():
        write_text_atomically(path, text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
