"""Correspondence search shared by all matchers: nearest reference points by KD-tree."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


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


def nearest_neighbours(tree: cKDTree, points: np.ndarray,
                       max_distance: float) -> Correspondences:
    """Pair each point with its nearest tree point, gated at ``max_distance``.

    Points with no tree point within ``max_distance`` get no pair (the KD-tree query
    is bounded, so far points cost little).
    """
    if len(points) == 0 or tree.n == 0:
        empty = np.zeros(0, dtype=int)
        return Correspondences(empty, empty, np.zeros(0))
    distance, index = tree.query(points, k=1, distance_upper_bound=max_distance)
    found = np.isfinite(distance)
    current = np.flatnonzero(found)
    return Correspondences(current, index[found], distance[found])


def k_nearest(tree: cKDTree, points: np.ndarray, k: int,
              max_distance: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """Return distances and indices (N, k) of the k nearest tree points.

    Missing neighbours (beyond ``max_distance`` or fewer than k points) have
    distance ``inf`` and index ``tree.n``.
    """
    k_eff = max(1, min(k, tree.n))
    distance, index = tree.query(points, k=k_eff, distance_upper_bound=max_distance)
    if k_eff == 1:
        distance, index = distance[:, None], index[:, None]
    if k_eff < k:
        pad = k - k_eff
        distance = np.pad(distance, ((0, 0), (0, pad)), constant_values=np.inf)
        index = np.pad(index, ((0, 0), (0, pad)), constant_values=tree.n)
    return distance, index
