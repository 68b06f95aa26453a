"""The spread of a benchmark figure over copies of a log that no sensor could tell apart.

One run of a log is an anecdote: a millimetre on every range can flip a discrete
choice (which reference decided a step, whether a match was accepted) and move the
whole trajectory. ``laser_odom_bench --perturb N`` runs N copies with 1 mm of range
noise (:func:`laser_odom.core.datasets.variants.with_range_noise`); this module sums
their rows up as the median and the worst copy of each figure, which is what a user
can expect and what the real-data tests assert on.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
import math
from typing import Iterable, Sequence

import numpy as np

from laser_odom.core.evaluation.benchmark import BenchRow

SPREAD_FIELDS = ('ate', 'drift_trans', 'drift_rot', 'rpe_trans_mean', 'rpe_rot_mean',
                 'failed', 'silent', 'nees_integrated', 'median_ms')
"""The row figures summed up over copies (the worst is the largest)."""

KEY_FIELDS = ('dataset', 'matcher', 'prior', 'deskew', 'reference')
"""What makes rows copies of one run: all but the copy."""


@dataclass
class SpreadRow:
    """The median and worst over copies of one dataset x matcher x prior x reference."""

    dataset: str
    matcher: str
    prior: str
    deskew: str
    reference: str
    copies: int
    median: dict[str, float]
    """Median of each of :data:`SPREAD_FIELDS` over the copies (NaN without values)."""
    worst: dict[str, float]
    """Largest of each over the copies (the worst: every figure is an error or a count)."""

    def as_dict(self) -> dict:
        """Return the row as a JSON-friendly dict."""
        return asdict(self)

    def cell(self, name: str, decimals: int) -> str:
        """Return ``median [worst]`` of one figure (one value when they agree, n/a if none)."""
        median, worst = self.median[name], self.worst[name]
        if math.isnan(median):
            return 'n/a'
        if self.copies == 1 or round(median, decimals) == round(worst, decimals):
            return f'{median:.{decimals}f}'
        return f'{median:.{decimals}f} [{worst:.{decimals}f}]'


def _values(rows: Sequence[BenchRow], name: str) -> np.ndarray:
    """Return one figure of the rows as floats, without the missing ones."""
    values = np.array([np.nan if getattr(row, name) is None else float(getattr(row, name))
                       for row in rows])
    return values[np.isfinite(values)]


def spread_rows(rows: Iterable[BenchRow]) -> list[SpreadRow]:
    """Group rows that differ only in their copy; return the median and worst of each group.

    Groups keep the order of their first row.
    """
    groups: dict[tuple, list[BenchRow]] = {}
    for row in rows:
        groups.setdefault(tuple(getattr(row, key) for key in KEY_FIELDS), []).append(row)
    spreads = []
    for key, members in groups.items():
        median, worst = {}, {}
        for name in SPREAD_FIELDS:
            values = _values(members, name)
            median[name] = float(np.median(values)) if values.size else math.nan
            worst[name] = float(np.max(values)) if values.size else math.nan
        spreads.append(SpreadRow(*key, copies=len(members), median=median, worst=worst))
    return spreads
