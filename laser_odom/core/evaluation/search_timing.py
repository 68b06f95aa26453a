"""Time the global search alone on a dataset (the benchmark's search table).

The correlative search (:func:`laser_odom.core.search.correlative_search`) runs only
when a prediction or a match fails, so a run's time per scan hides it; this times it
on its own, from zero motion as ``prior: none`` would, so its cost per search can be
compared across datasets and beam counts.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
import time

import numpy as np

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import GlobalSearchConfig, MountingConfig, ScanConfig
from laser_odom.core.events import EventLog
from laser_odom.core.preprocess.validation import ScanValidator
from laser_odom.core.search import correlative_search
from laser_odom.core.trajectory import Dataset

SEARCH_PAIRS = 50
"""Scan pairs, spread over a dataset, on which the global search alone is timed."""


@dataclass
class SearchTimingRow:
    """The global search alone on one dataset: time per search and where it goes."""

    dataset: str
    beams: int
    searches: int
    median_ms: float
    p95_ms: float
    grid_ms: float
    tree_ms: float
    nodes: int
    exhaustive: float

    def as_dict(self) -> dict:
        """Return the row as a JSON-friendly dict."""
        return asdict(self)


def search_timing(dataset: Dataset, config: GlobalSearchConfig | None = None,
                  pairs: int = SEARCH_PAIRS) -> SearchTimingRow:
    """Time the global search over its window on pairs of consecutive scans.

    The guess is zero motion, as with ``prior: none``; one search warms up first.
    Medians of the whole search, of rasterising and bounding the reference (grid) and
    of scoring the tree, the median count of scored nodes and the share of searches
    that were exhaustive.
    """
    config = config if config is not None else GlobalSearchConfig()
    window = config.window()
    validator = ScanValidator(ScanConfig(), MountingConfig(), EventLog(lambda message: None))
    starts = np.unique(np.linspace(0, max(len(dataset.scans) - 2, 0), pairs + 1).astype(int))
    results, times = [], []
    for index in starts:
        reference, _ = validator.check(dataset.scans[index])
        current, _ = validator.check(dataset.scans[index + 1])
        if reference is None or current is None:
            continue
        started = time.perf_counter()
        result = correlative_search(reference, current, se2.pose(), window,
                                    config.global_search_candidates)
        if result is not None:
            times.append(time.perf_counter() - started)
            results.append(result)
    times, results = times[1:], results[1:]
    beams = len(dataset.scans[0].ranges) if dataset.scans else 0
    if not results:
        nan = float('nan')
        return SearchTimingRow(dataset.name, beams, 0, nan, nan, nan, nan, 0, nan)
    return SearchTimingRow(
        dataset.name, beams, len(results), float(np.median(times) * 1e3),
        float(np.percentile(times, 95) * 1e3),
        float(np.median([r.grid_seconds for r in results]) * 1e3),
        float(np.median([r.tree_seconds for r in results]) * 1e3),
        int(np.median([r.nodes for r in results])),
        float(np.mean([r.exhaustive for r in results])))
