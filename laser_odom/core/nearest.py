"""Exact gated nearest-neighbour search in a 2D scan, by bearing (compiled).

A laser scan is a ring of points around its sensor, so its points sorted by bearing
are a natural index: any point within ``d`` of a query ``q`` (``|q| > d``) is seen from
the origin within ``asin(d / |q|)`` of ``q``'s own bearing. A query therefore finds its
insertion place among the sorted bearings (binary search) and walks outward on both
sides while the angular gap can still hide a closer point - no trigonometry: the bound
``|q| sin g`` is the cross product of ``q`` with the point's unit direction - and the
gap narrows as closer points turn up. The answer is exact - the same nearest
point a KD-tree returns - for any point set, de-skewed or not; the walk is short
because the ring is sampled in angle (the projective association of CSM's
correspondence search and of rf2o, without assuming beam order). A query closer to
the origin than ``d`` walks the whole ring.

Built in O(n log n) once per scan (sorting), queried in O(log n + k) per point inside
one compiled loop; numba caches the machine code between runs where it can write.
"""

from __future__ import annotations

import math

import numba
import numpy as np

TWO_PI = 2.0 * math.pi


class BearingIndex:
    """The points of one scan sorted by bearing from the origin, for nearest queries."""

    def __init__(self, points: np.ndarray) -> None:
        """Sort ``points`` (N, 2) by bearing; queries answer with indices into ``points``."""
        points = np.ascontiguousarray(points, dtype=float)
        bearings = np.arctan2(points[:, 1], points[:, 0])
        self.order = np.argsort(bearings, kind='stable')
        self.bearings = np.ascontiguousarray(bearings[self.order])
        self.sorted_points = np.ascontiguousarray(points[self.order])
        norm = np.hypot(self.sorted_points[:, 0], self.sorted_points[:, 1])
        self.directions = np.column_stack((np.cos(self.bearings), np.sin(self.bearings)))
        self.directions[norm > 0.0] = (self.sorted_points[norm > 0.0]
                                       / norm[norm > 0.0, None])
        self.n = int(points.shape[0])

    def nearest(self, queries: np.ndarray, max_distance: float
                ) -> tuple[np.ndarray, np.ndarray]:
        """Return the distance to, and index of, each query's nearest point within reach.

        Like ``cKDTree.query(queries, k=1, distance_upper_bound=max_distance)``: a query
        with no point within ``max_distance`` gets distance ``inf`` and index ``n``.
        """
        queries = np.ascontiguousarray(queries, dtype=float).reshape(-1, 2)
        return nearest_by_bearing(self.sorted_points, self.bearings, self.directions,
                                  self.order, queries, float(max_distance))


@numba.njit(cache=True, nogil=True, inline='always')
def _walk(points: np.ndarray, directions: np.ndarray, order: np.ndarray, qx: float,
          qy: float, first: int, direction: int, steps: int, best2: float,
          best: int) -> tuple[float, int, int]:
    """Walk the ring from ``first`` in ``direction`` (+1 or -1) while a closer point may lie.

    A point whose bearing is ``g`` from the query's is at least ``|q| sin g`` away
    (``g`` <= 90 deg; ``|q x u|`` with ``u`` its unit direction) or ``|q|`` away
    (beyond). Bearings along the walk move away from the query's monotonically, so
    once that bound exceeds the best distance every point further along is farther
    too. Returns the best squared distance and index, and the points visited.
    """
    n = points.shape[0]
    reach = math.sqrt(best2)
    radius = math.sqrt(qx * qx + qy * qy)
    j = first
    visited = 0
    while visited < steps:
        if j >= n:
            j -= n
        elif j < 0:
            j += n
        ux, uy = directions[j, 0], directions[j, 1]
        bound = abs(qx * uy - qy * ux) if qx * ux + qy * uy >= 0.0 else radius
        if bound > reach:
            break
        dx, dy = points[j, 0] - qx, points[j, 1] - qy
        d2 = dx * dx + dy * dy
        if d2 < best2 or (d2 == best2 and best >= 0 and order[j] < order[best]):
            best2, best = d2, j
            reach = math.sqrt(best2)
        j += direction
        visited += 1
    return best2, best, visited


@numba.njit(cache=True, nogil=True)
def nearest_by_bearing(points: np.ndarray, bearings: np.ndarray, directions: np.ndarray,
                       order: np.ndarray, queries: np.ndarray, max_distance: float
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Compiled kernel of :meth:`BearingIndex.nearest` (points sorted by bearing)."""
    n = points.shape[0]
    count = queries.shape[0]
    distance = np.full(count, np.inf)
    index = np.full(count, n, dtype=np.int64)
    if n == 0:
        return distance, index
    limit2 = max_distance * max_distance
    for i in range(count):
        qx, qy = queries[i, 0], queries[i, 1]
        start = np.searchsorted(bearings, math.atan2(qy, qx))
        best2, best, right = _walk(points, directions, order, qx, qy, start, 1, n, limit2, -1)
        best2, best, _ = _walk(points, directions, order, qx, qy, start - 1, -1, n - right,
                               best2, best)
        if best >= 0:
            distance[i] = math.sqrt(best2)
            index[i] = order[best]
    return distance, index
