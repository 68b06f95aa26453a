"""Documented figures, rendered from the committed benchmark results (``make docs``).

Every block between ``<!-- figures:NAME:begin -->`` and ``<!-- figures:NAME:end -->``
in the pages of ``docs/`` (the real-log, local-map and fast-robot tables and the
per-scan times in ``docs/benchmark.md``, the NEES in ``docs/node.md``), and the block
"Measured with these values" in each ``config/<matcher>.yaml``, are written from two
``laser_odom_bench --json`` results (``make figures``), which record their date,
machine and library versions: ``test/figures/benchmark.json`` (the real logs and the
simulated office) and ``test/figures/fast.json`` (the re-stamped fast-robot logs, the
``fast`` block). A block may sit in any of those pages (:data:`BLOCKS` renders it
wherever its markers are), but in exactly one. The README holds no figures: it is a
guide, and says which option when in words. Nothing is typed by hand: ``test_docs``
fails when the files and the JSON disagree, and ``test_real_data`` fails when the code
falls more than 5 % behind the worst copy of a committed figure.

Figures are what a user gets: each run is made on copies of the log as a bag delivers
it (float32 LaserScan), with 1 mm of range noise (``laser_odom_bench --perturb N``);
the documents quote the median copy, and the map and fast-robot tables the worst
beside it (reading the results: :mod:`.figures_result`).
"""

from __future__ import annotations

import argparse
import itertools
from pathlib import Path
import sys
from typing import Any, Mapping, Sequence

from laser_odom.io.text_output import write_text_atomically
from laser_odom.tools.figures_result import (  # noqa: F401 (the tests' import place)
    copies_phrase, count, FAST_JSON, FAST_LOGS, FAST_MATCHERS, FAST_PRIORS, figure, FIGURES_JSON,
    FiguresError, load_figures, MATCHERS, PRIOR, REAL_LOGS, REFERENCES, regression, ROOT,
    spread_cell, TIMING_DATASETS)

DOCUMENTS = ('docs/benchmark.md', 'docs/node.md')
"""Documents (relative to the source tree) whose figure blocks ``make docs`` renders."""

CONFIG_MARKERS = ('# figures:begin', '# figures:end')


def markers(block: str) -> tuple[str, str]:
    """Return the begin and end marker lines of a figure block in Markdown."""
    return f'<!-- figures:{block}:begin -->', f'<!-- figures:{block}:end -->'


def real_log_table(payload: Mapping[str, Any]) -> str:
    """Markdown table: mean RPE (m / deg), ATE (m) and failed steps per matcher and log.

    Each figure is the median copy's (the text around the block says over how many).
    """
    beams = {name: figure(payload, name, MATCHERS[0])['beams'] for name, _ in REAL_LOGS}
    heading = ' | '.join(f'{name} ({beams[name]} beams)' for name, _ in REAL_LOGS)
    lines = [f'| matcher | {heading} |',
             '|---|' + '---|' * len(REAL_LOGS)]
    for matcher in MATCHERS:
        cells = []
        for name, _ in REAL_LOGS:
            row = figure(payload, name, matcher)
            cells.append(f'{row["rpe_trans_mean"]:.3f} / {row["rpe_rot_mean"]:.2f} / '
                         f'{row["ate"]:.2f} / {count(row["failed"])}')
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
    """Return the real-log NEES over 100 steps and whole logs, every matcher (median copy)."""
    rows = [figure(payload, name, m) for name, _ in REAL_LOGS for m in MATCHERS]

    def spread(key: str) -> str:
        values = [row[key] for row in rows]
        return f'{min(values):.0f}-{max(values):.0f}'

    noise = rows[0]
    return (f'On the real logs (`laser_odom_bench --nees`, {payload.get("date", "undated")}'
            f'{copies_phrase(noise)}, {100 * noise["reference_noise_m"]:.0f} cm / '
            f'{noise["reference_noise_deg"]:.0f} deg of reference noise allowed for) the NEES '
            f'is {spread("nees_100")} over 100 steps and {spread("nees_integrated")} over a '
            'whole log.\n')


def config_block(payload: Mapping[str, Any], matcher: str) -> str:
    """Comment lines for ``config/<matcher>.yaml``: the matcher's figures on each log."""
    rows = [(label, figure(payload, name, matcher)) for name, label in REAL_LOGS]
    lines = ['# Measured with these values by laser_odom_bench (constant-velocity prior, '
             f'{payload.get("date", "undated")}):']
    if rows[0][1].get('copies'):
        lines.append(f'# the median of {rows[0][1]["copies"]} copies of each log with 1 mm '
                     'range noise;')
    lines += ['# mean RPE between consecutive reference poses, ATE after SE(2) alignment, '
              'failed steps',
              '# (RPE > 0.5 m or 10 deg) and median time per scan:']
    for label, row in rows:
        lines.append(f'#   {label:<10} {row["rpe_trans_mean"]:.4f} m  '
                     f'{row["rpe_rot_mean"]:.3f} deg  ATE {row["ate"]:.2f} m  '
                     f'{count(row["failed"])} failed  {row["median_ms"]:4.1f} ms '
                     f'({row["beams"]} beams)')
    return '\n'.join(lines) + '\n'


def replace_between(text: str, markers: tuple[str, str], body: str, where: str) -> str:
    """Return ``text`` with what lies between the two marker lines replaced by ``body``."""
    begin, end = markers
    if text.count(begin) != 1 or text.count(end) != 1 or text.index(begin) > text.index(end):
        raise FiguresError(f'{where} needs one {begin!r} line and one {end!r} line after it')
    head, rest = text.split(begin, 1)
    tail = rest.split(end, 1)[1]
    return f'{head}{begin}\n{body}{end}{tail}'


def failures(row: Mapping[str, Any]) -> str:
    """Return the worst copy's failed steps and, in brackets, the silent ones among them."""
    worst = row.get('worst', row)
    return f'{count(worst.get("failed"))} ({count(worst.get("silent"))})'


def map_table(payload: Mapping[str, Any]) -> str:
    """Markdown table: scan to scan -> local map, per matcher and log, and the time cost.

    Each cell holds, in both modes, the median [worst] copy's drift over 50 m of path
    (% of the path) and ATE (m), then the most failed (silent) steps of any copy; the
    last column the median time per scan on fr079 in both.
    """
    lines = ['| matcher | ' + ' | '.join(f'{name}: drift %, ATE m, failed (silent)'
                                         for name, _ in REAL_LOGS)
             + f' | {TIMING_DATASETS[0]}: ms per scan |',
             '|---|' + '---|' * (len(REAL_LOGS) + 1)]
    for matcher in MATCHERS:
        cells = []
        for name, _ in REAL_LOGS:
            scan, mapped = (figure(payload, name, matcher, reference)
                            for reference in REFERENCES)
            cells.append(', '.join(
                f'{spread_cell(scan, key, decimals)} -> {spread_cell(mapped, key, decimals)}'
                for key, decimals in (('drift_trans', 2), ('ate', 2)))
                + f', {failures(scan)} -> {failures(mapped)}')
        scan, mapped = (figure(payload, TIMING_DATASETS[0], matcher, reference)
                        for reference in REFERENCES)
        cells.append(f'{scan["median_ms"]:.1f} -> {mapped["median_ms"]:.1f}')
        lines.append(f'| `{matcher}` | ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines) + '\n'


def fast_table(payload: Mapping[str, Any]) -> str:
    """Markdown table of the fast-robot logs: prior none vs constant velocity, both modes.

    Per log and matcher, for each prior x reference: failed / silent steps and the ATE
    (m), each the median [worst] copy; then a line saying when, where and over how many
    copies (the result of :data:`FAST_JSON`, loaded as ``payload['fast']``).
    """
    fast = payload.get('fast')
    if fast is None:
        raise FiguresError(f'the fast block needs the fast-robot result ({FAST_JSON.name}; '
                           'load_figures(fast=...)): run make figures')
    columns = list(itertools.product(FAST_PRIORS, REFERENCES))
    lines = ['| log | matcher | ' + ' | '.join(f'`{prior}`, `{reference}`'
                                               for prior, reference in columns) + ' |',
             '|---|---|' + '---|' * len(columns)]
    copies = set()
    for dataset, matcher in itertools.product(FAST_LOGS, FAST_MATCHERS):
        rows = [figure(fast, dataset, matcher, reference, prior)
                for prior, reference in columns]
        copies.update(row.get('copies', 1) for row in rows)
        cells = [f'{spread_cell(row, "failed")} / {spread_cell(row, "silent")}, '
                 f'{spread_cell(row, "ate", 2)}' for row in rows]
        lines.append(f'| {dataset} ({rows[0]["steps"]} steps) | `{matcher}` | '
                     + ' | '.join(cells) + ' |')
    machine = fast.get('machine', 'unknown machine').split(';')[0]
    measured = ('one run of each, as received' if copies == {1} else
                f'median [worst] of {"/".join(map(str, sorted(copies)))} copies with 1 mm '
                'range noise')
    return '\n'.join(lines) + (f'\n\nFailed / silent steps, ATE m; {measured} '
                               f'(`laser_odom_bench`, {machine}, '
                               f'{fast.get("date", "undated")}).\n')


BLOCKS = {'table': real_log_table, 'speed': speed_sentence, 'nees': nees_sentence,
          'map': map_table, 'fast': fast_table}
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


def main(argv: Sequence[str] | None = None) -> int:
    """Rewrite the documented figures from the committed benchmark results."""
    parser = argparse.ArgumentParser(prog='python -m laser_odom.tools.figures',
                                     description=__doc__.splitlines()[0])
    parser.add_argument('--json', type=Path, default=FIGURES_JSON,
                        help='benchmark result (default: test/figures/benchmark.json)')
    parser.add_argument('--fast-json', type=Path, default=FAST_JSON,
                        help='benchmark result on the fast-robot logs (default: '
                        'test/figures/fast.json)')
    parser.add_argument('--root', type=Path, default=ROOT,
                        help='source tree whose docs/ and config/ to update '
                        "(default: this package's)")
    args = parser.parse_args(argv)
    try:
        payload = load_figures(args.json, fast=args.fast_json)
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
