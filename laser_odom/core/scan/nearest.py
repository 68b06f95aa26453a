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

from laser_odom.core.scan.bearings import approximate_atan2, bearing_place, settled_place

HINT_STEPS = 16
"""Steps from a hinted position to the query's place among the bearings before a
binary search takes over."""


class BearingIndex:
    """The points of one scan sorted by bearing from the origin, for nearest queries."""

    def __init__(self, points: np.ndarray) -> None:
        """Sort ``points`` (N, 2) by bearing; queries answer with indices into ``points``."""
        self.order, self.bearings, self.sorted_points, self.directions = _sort_by_bearing(
            np.ascontiguousarray(points, dtype=float).reshape(-1, 2))
        self.n = int(self.order.shape[0])

    def nearest(self, queries: np.ndarray, max_distance: float
                ) -> tuple[np.ndarray, np.ndarray]:
        """Return the distance to, and index of, each query's nearest point within reach.

        Like ``cKDTree.query(queries, k=1, distance_upper_bound=max_distance)``: a query
        with no point within ``max_distance`` gets distance ``inf`` and index ``n``.
        """
        queries = np.ascontiguousarray(queries, dtype=float).reshape(-1, 2)
        return nearest_by_bearing(self.sorted_points, self.bearings, self.directions,
                                  self.order, queries, float(max_distance),
                                  np.full(queries.shape[0], -1, dtype=np.int64))

    def k_nearest(self, queries: np.ndarray, k: int, max_distance: float = np.inf
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Return distances and indices (N, k) of each query's k nearest points, nearest first.

        Like ``cKDTree.query(queries, k, distance_upper_bound=max_distance)``: missing
        neighbours (beyond ``max_distance``, or fewer than k points) have distance
        ``inf`` and index ``n``.
        """
        queries = np.ascontiguousarray(queries, dtype=float).reshape(-1, 2)
        return k_nearest_by_bearing(self.sorted_points, self.bearings, self.directions,
                                    self.order, queries, int(k), float(max_distance))


@numba.njit(cache=True, nogil=True)
def _sort_by_bearing(points: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Return the order by bearing, the sorted bearings, points and unit directions.

    A point at the origin has bearing 0 and direction (1, 0) (its distance bound,
    ``|q x u|`` or ``|q|``, still never exceeds its true distance ``|q|``).
    """
    n = points.shape[0]
    bearings = np.empty(n)
    for i in range(n):
        bearings[i] = math.atan2(points[i, 1], points[i, 0])
    order = np.argsort(bearings)
    sorted_points = np.empty((n, 2))
    directions = np.empty((n, 2))
    for j in range(n):
        x, y = points[order[j], 0], points[order[j], 1]
        sorted_points[j, 0], sorted_points[j, 1] = x, y
        norm = math.sqrt(x * x + y * y)
        if norm > 0.0:
            directions[j, 0], directions[j, 1] = x / norm, y / norm
        else:
            directions[j, 0], directions[j, 1] = 1.0, 0.0
    return order, bearings[order], sorted_points, directions


@numba.njit(cache=True, nogil=True, inline='always')
def _bearing_bound2(directions: np.ndarray, j: int, qx: float, qy: float,
                    radius2: float) -> float:
    """Squared lower bound on the distance from query ``q`` to sorted point ``j``.

    ``(q x u)^2`` (the squared distance from q to the ray along ``u``, its direction)
    within 90 deg of the query's bearing, else ``|q|^2`` (``radius2``). Squared, so that
    the walks compare it with squared distances and take no square root per step.
    """
    ux, uy = directions[j, 0], directions[j, 1]
    if qx * ux + qy * uy >= 0.0:
        cross = qx * uy - qy * ux
        return cross * cross
    return radius2


@numba.njit(cache=True, nogil=True)
def k_nearest_by_bearing(points: np.ndarray, bearings: np.ndarray, directions: np.ndarray,
                         order: np.ndarray, queries: np.ndarray, k: int, max_distance: float
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Compiled kernel of :meth:`BearingIndex.k_nearest` (points sorted by bearing).

    Each query walks the ring from its place among the sorted bearings, both ways at
    once (always on the side whose next point may be nearer), keeping its k nearest
    (squared distances ascending, with the gate's square until k are found). A point
    whose bearing is ``g`` from the query's is at least ``|q| sin g`` away (``g`` <= 90
    deg; ``|q x u|`` with ``u`` its unit direction) or ``|q|`` away (beyond); bearings
    along a walk move away from the query's monotonically, so once that bound exceeds
    the k-th distance every point further along is farther too. The two sides together
    visit each point at most once; ties go to the lower original index, so the answer
    does not depend on the walk.
    """
    n = points.shape[0]
    count = queries.shape[0]
    k = max(k, 1)
    distance = np.full((count, k), np.inf)
    index = np.full((count, k), n, dtype=np.int64)
    if n == 0:
        return distance, index
    limit2 = max_distance * max_distance
    best2 = np.empty(k)
    best = np.empty(k, dtype=np.int64)
    for i in range(count):
        qx, qy = queries[i, 0], queries[i, 1]
        best2[:] = limit2
        best[:] = -1
        found = 0
        radius2 = qx * qx + qy * qy
        start = bearing_place(bearings, qx, qy)
        # Walk both ways at once, always on the side whose next point may lie closer, so
        # that the k-th distance (the reach) shrinks as early as it can. Positions wrap
        # around the ring by comparison (no integer division in the loop).
        right = start if start < n else 0
        left = start - 1 if start > 0 else n - 1
        bound_right = _bearing_bound2(directions, right, qx, qy, radius2)
        bound_left = _bearing_bound2(directions, left, qx, qy, radius2)
        for _ in range(n):
            if min(bound_right, bound_left) > best2[k - 1]:
                break
            if bound_right <= bound_left:
                j = right
                right = right + 1 if right + 1 < n else 0
                bound_right = _bearing_bound2(directions, right, qx, qy, radius2)
            else:
                j = left
                left = left - 1 if left > 0 else n - 1
                bound_left = _bearing_bound2(directions, left, qx, qy, radius2)
            dx, dy = points[j, 0] - qx, points[j, 1] - qy
            d2 = dx * dx + dy * dy
            if d2 <= best2[k - 1]:
                # Insert among the ``found`` entries only: the unfilled tail (the gate's
                # square) needs no shifting, and nearby points mostly arrive in order.
                slot = found
                while slot > 0 and (d2 < best2[slot - 1] or (
                        d2 == best2[slot - 1] and order[j] < order[best[slot - 1]])):
                    slot -= 1
                if slot < k:
                    for m in range(min(found, k - 1), slot, -1):
                        best2[m], best[m] = best2[m - 1], best[m - 1]
                    best2[slot], best[slot] = d2, j
                    found = min(found + 1, k)
        for m in range(k):
            if best[m] >= 0:
                distance[i, m] = math.sqrt(best2[m])
                index[i, m] = order[best[m]]
    return distance, index


@numba.njit(cache=True, nogil=True)
def nearest_by_bearing(points: np.ndarray, bearings: np.ndarray, directions: np.ndarray,
                       order: np.ndarray, queries: np.ndarray, max_distance: float,
                       hints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the distance to and index of each query's nearest point (k = 1).

    ``hints`` (one sorted position per query, -1 for none) are where the previous
    search of the same point ended: an ICP iteration moves the points little, so the
    hinted point bounds the search at once and the query's place among the bearings
    is a few steps away. A query without a hint (a run's first iteration) takes the
    previous query's answer instead: the points of a scan come in beam order, so
    consecutive ones lie a beam apart. The answer does not depend on the hints (the
    search stays exact: any point's distance bounds the nearest's); they are
    overwritten with this search's sorted positions (-1: none found).
    """
    n = points.shape[0]
    count = queries.shape[0]
    distance = np.full(count, np.inf)
    index = np.full(count, n, dtype=np.int64)
    if n == 0:
        hints[:] = -1
        return distance, index
    limit2 = max_distance * max_distance
    for i in range(count):
        qx, qy = queries[i, 0], queries[i, 1]
        radius2, bearing = qx * qx + qy * qy, approximate_atan2(qy, qx)
        best2, best = limit2, -1
        hint = hints[i] if hints[i] >= 0 or i == 0 else hints[i - 1]
        start = -1
        if hint >= 0:
            dx, dy = points[hint, 0] - qx, points[hint, 1] - qy
            if dx * dx + dy * dy <= limit2:
                best2, best = dx * dx + dy * dy, hint
            start = hint  # moved to the first position whose bearing is >= the query's
            for _ in range(HINT_STEPS):
                if start > 0 and bearings[start - 1] >= bearing:
                    start -= 1
                elif start < n and bearings[start] < bearing:
                    start += 1
                else:
                    break
            else:
                start = -1
        if start < 0:
            start = np.searchsorted(bearings, bearing)
        if not settled_place(bearings, bearing, start):  # the exact bearing decides
            start = np.searchsorted(bearings, math.atan2(qy, qx))
        # The walks of :func:`k_nearest_by_bearing` on scalars: k = 1 is every matcher's.
        steps = n
        for direction in (1, -1):
            j = start if direction == 1 else start - 1
            visited = 0
            while visited < steps:
                if j >= n:
                    j -= n
                elif j < 0:
                    j += n
                if _bearing_bound2(directions, j, qx, qy, radius2) > best2:
                    break
                dx, dy = points[j, 0] - qx, points[j, 1] - qy
                d2 = dx * dx + dy * dy
                if d2 < best2 or (d2 == best2 and best >= 0 and order[j] < order[best]):
                    best2, best = d2, j
                j += direction
                visited += 1
            steps = n - visited
        hints[i] = best
        if best >= 0:
            distance[i] = math.sqrt(best2)
            index[i] = order[best]
    return distance, index
