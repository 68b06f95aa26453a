"""How ``laser_odom_bench`` runs its rows: copies of each dataset, side by side on request.

Every copy of a dataset is what a bag of it holds (float32 LaserScan fields); with
``--perturb N`` the copies carry 1 mm of range noise each, so that a figure is reported
with its spread (:mod:`laser_odom.core.evaluation.spread`), and ``--jobs N`` runs the
copies in N processes.
"""

from __future__ import annotations

import itertools
import sys
import time
from typing import Any, Mapping, Sequence, TextIO

from laser_odom.core.configuration.pipeline import pipeline_config_from_params
from laser_odom.core.datasets import as_received, with_range_noise
from laser_odom.core.evaluation.benchmark import (
    benchmark_run, BenchRow, GRIDS, SIMULATED, simulated_scanner, wheel_odometry_row)
from laser_odom.core.evaluation.consistency import ReferenceNoise
from laser_odom.core.trajectory import Dataset
from laser_odom.tools.quiet import warnings_silenced


class ProgressBar:
    """A one-line progress bar on stderr, redrawn at most every 0.2 s."""

    def __init__(self, label: str, total: int, stream: TextIO | None = None) -> None:
        """Start a bar for ``total`` items on ``stream`` (default: the current stderr)."""
        self.label, self.total = label, max(total, 1)
        self.stream = stream if stream is not None else sys.stderr
        self.last_draw = 0.0

    def __call__(self, done: int) -> None:
        """Redraw with ``done`` items finished."""
        now = time.monotonic()
        if now - self.last_draw < 0.2 and done < self.total:
            return
        self.last_draw = now
        filled = int(30 * done / self.total)
        self.stream.write(f'\r{self.label:<52} [{"#" * filled}{"." * (30 - filled)}] '
                          f'{done}/{self.total}')
        if done >= self.total:
            self.stream.write('\n')
        self.stream.flush()


def simulated_here(name: str) -> bool:
    """Tell whether a dataset is simulated by the benchmark (truth as its reference)."""
    return name in SIMULATED or any(name in grid for grid in GRIDS.values())


def dataset_copies(dataset: Dataset, copies: int, sigma: float) -> list[tuple[int, Dataset]]:
    """Return the dataset as the node receives it (copy 0), or ``copies`` noisy copies.

    Every copy is what a bag of it holds (float32 LaserScan fields,
    :func:`.datasets.variants.as_received`); copy k > 0 first has Gaussian noise of
    ``sigma`` on every range, drawn from seed k.
    """
    if copies == 0:
        return [(0, as_received(dataset))]
    return [(seed, as_received(with_range_noise(dataset, seed, sigma)))
            for seed in range(1, copies + 1)]


def _dataset_rows(dataset: Dataset, copy: int, matchers: Sequence[str],
                  priors: Sequence[str], deskews: Sequence[str | None],
                  references: Sequence[str | None], values: Mapping[str, Any],
                  noise: ReferenceNoise, progress: bool) -> list[BenchRow]:
    """Run every matcher x prior x deskew x reference on one copy of a dataset."""
    rows: list[BenchRow] = []
    name = dataset.name
    has_odometry = len(dataset.odometry) > 0
    if copy <= 1 and 'odom' in priors and has_odometry and len(dataset.reference):
        rows.append(wheel_odometry_row(dataset))
    for matcher in matchers:
        for prior in priors:
            if prior == 'odom' and not has_odometry:
                continue
            for deskew, reference in itertools.product(deskews, references):
                label = ' '.join(filter(None, (name, matcher, prior, deskew, reference,
                                               f'copy {copy}' if copy else None)))
                bar = ProgressBar(label, len(dataset.scans)) if progress else None
                config = pipeline_config_from_params({**values, 'matcher': matcher})
                if simulated_here(name):
                    config = simulated_scanner(config)
                row = benchmark_run(dataset, matcher, prior, progress=bar, config=config,
                                    deskew=deskew, reference_noise=noise,
                                    reference=reference)
                row.copy = copy
                rows.append(row)
    return rows


_TASKS: list[tuple] = []
"""The copies a ``--jobs`` pool runs (its forked workers inherit them, nothing is pickled
but an index)."""


def _run_task(index: int) -> list[BenchRow]:
    """Run the rows of one dataset copy (:func:`_dataset_rows`) in a pool worker."""
    with warnings_silenced(True):
        return _dataset_rows(*_TASKS[index])


def run_tasks(tasks: list[tuple], jobs: int) -> list[list[BenchRow]]:
    """Run every dataset copy's rows, in ``jobs`` processes side by side when above 1.

    Each copy's rows are run whole in one process, in the order given; the results are
    the same as one after another (every run is deterministic), the timings are not
    (the processes share the machine).
    """
    if jobs == 1 or len(tasks) < 2:
        return [_dataset_rows(*task) for task in tasks]
    import multiprocessing
    _TASKS[:] = tasks
    try:
        with multiprocessing.get_context('fork').Pool(min(jobs, len(tasks))) as pool:
            return pool.map(_run_task, range(len(tasks)), chunksize=1)
    finally:
        _TASKS.clear()
