"""Correspondence search shared by all matchers: nearest reference points by bearing.

Every matcher pairs through a :class:`laser_odom.core.scan.nearest.BearingIndex` (exact
gated nearest-neighbour search, compiled), built once per reference scan.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from laser_odom.core.scan.nearest import BearingIndex


@dataclass
class Correspondences:
    """Pairs (current point ``current[i]``, reference point ``reference[i]``).

    ``current`` indexes the current scan's points, ``reference`` the reference
    scan's points, ``distance`` is the Euclidean distance of each pair.
    """

    current: np.ndarray
    reference: np.ndarray
    distance: np.ndarray

    def __len__(self) -> int:
        """Return the number of pairs."""
        return int(self.current.shape[0])

    def subset(self, keep: np.ndarray) -> 'Correspondences':
        """Return the pairs selected by a boolean mask or index array."""
        return Correspondences(self.current[keep], self.reference[keep], self.distance[keep])


def nearest_neighbours(index: BearingIndex, points: np.ndarray,
                       max_distance: float) -> Correspondences:
    """Pair each point with its nearest indexed point, gated at ``max_distance``.

    Points with no indexed point within ``max_distance`` get no pair (the search is
    bounded, so far points cost little).
    """
    if len(points) == 0 or index.n == 0:
        empty = np.zeros(0, dtype=int)
        return Correspondences(empty, empty, np.zeros(0))
    distance, index = index.nearest(points, max_distance)
    found = np.isfinite(distance)
    current = np.flatnonzero(found)
    return Correspondences(current, index[found], distance[found])
