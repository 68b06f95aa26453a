"""Implicit moving-least-squares (IMLS) surface of a 2D scan and informative points.

The reference scan is read as the zero set of Kolluri's IMLS function ("Provably
good moving least squares", SODA 2005; used for scan-to-model matching by Deschaud,
"IMLS-SLAM: scan-to-model matching based on 3D data", ICRA 2018, eq. 1)::

    I(x) = sum_i W_i(x) ((x - p_i) . n_i) / sum_i W_i(x),   W_i(x) = exp(-|x - p_i|^2 / h^2)

over the reference points p_i (with normals n_i) within a radius of x. I(x) is the
weighted mean of the signed distances of x to the tangent lines of its neighbours:
on a straight wall it is the exact signed distance, on a circle of radius R it is
offset by about h^2 / 4R (the weights reach around the bend). A query point is
projected onto the surface along the normal of its nearest reference point,
``y = x - I(x) n`` (IMLS-SLAM section III-C).

Deschaud keeps only a few informative current points (IMLS-SLAM section III-B): each
point scores, for every degree of freedom, how much a motion along it changes the
point's distance to its tangent line, weighted by how planar its neighbourhood is;
the best points of every list are kept so that no direction becomes unobservable.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math

import numba
import numpy as np

from laser_odom.core.scan.laser_scan import ScanPoints
from laser_odom.core.scan.nearest import BearingIndex, k_nearest_by_bearing
from laser_odom.core.scan.normals import estimate_normals
from laser_odom.core.se2 import move_points


@dataclass
class SurfaceModel:
    """A scan's points and normals, padded for masked neighbour lookups.

    Row ``n`` of ``points`` and ``normals`` is a zero pad that missing neighbours
    (index ``index.n``) point to; ``usable[n]`` is False, as is ``usable`` of every
    point without a well-defined normal. Derived once: ``offset`` is ``p_i . n_i`` (the
    tangent-line distance is ``x . n_i - offset_i``); ``curvature`` is padded with 0.5
    (no planarity).
    """

    index: BearingIndex
    points: np.ndarray
    normals: np.ndarray
    usable: np.ndarray
    curvature: np.ndarray
    offset: np.ndarray = field(init=False)
    ranking: np.ndarray | None = field(default=None, init=False)
    """The selection lists of :func:`candidate_ranking`, once asked for."""

    def __post_init__(self) -> None:
        """Precompute the tangent-line offsets."""
        self.offset = np.einsum('nd,nd->n', self.points, self.normals)


@dataclass
class SurfaceSample:
    """The IMLS surface at query points.

    ``value`` is I(x) (0 where undefined), ``normal`` the unit normal of each query's
    nearest usable reference point, ``defined`` whether the query had at least the
    required number of usable neighbours, ``count`` how many it had, and
    ``mean_normal`` the kernel-weighted mean of the neighbours' normals, normalised
    (the first-order gradient of I near the surface, Kolluri 2005), and ``nearest``
    the index of the nearest usable reference point (the point count where undefined).
    """

    value: np.ndarray
    normal: np.ndarray
    defined: np.ndarray
    count: np.ndarray
    mean_normal: np.ndarray
    nearest: np.ndarray


def surface_model(scan: ScanPoints, normal_neighbours: int, normal_radius: float,
                  normal_min_neighbours: int, normal_extent: float | None = None
                  ) -> SurfaceModel:
    """Return the (cached) IMLS model of a scan: padded points, normals, usability.

    Normals come from the shared :func:`estimate_normals`, whose result is cached on
    the scan, so a scan's normals are computed once: when it is the current scan
    (for point selection) and reused when it becomes the reference.
    """
    key = ('imls_model', normal_neighbours, normal_radius, normal_min_neighbours, normal_extent)
    cached = scan.cache.get(key)
    if cached is not None:
        return cached
    surface = estimate_normals(scan, normal_neighbours, normal_radius, normal_min_neighbours,
                               extent=normal_extent)
    pad = np.zeros((1, 2))
    model = SurfaceModel(
        index=scan.bearing_index,
        points=np.vstack((scan.points, pad)),
        normals=np.vstack((surface.normals, pad)),
        usable=np.append(surface.valid, False),
        curvature=np.append(surface.curvature, 0.5))
    scan.cache[key] = model
    return model


def model_from_arrays(points: np.ndarray, normals: np.ndarray,
                      usable: np.ndarray | None = None) -> SurfaceModel:
    """Build a model from explicit points and unit normals (analytic shapes, tests)."""
    n = points.shape[0]
    ok = np.ones(n, dtype=bool) if usable is None else np.asarray(usable, dtype=bool)
    pad = np.zeros((1, 2))
    return SurfaceModel(BearingIndex(points), np.vstack((points, pad)), np.vstack((normals, pad)),
                        np.append(ok, False), np.zeros(n + 1))


def implicit_surface(model: SurfaceModel, queries: np.ndarray, h: float, radius: float,
                     max_neighbours: int, min_neighbours: int) -> SurfaceSample:
    """Evaluate the IMLS function I(x) (IMLS-SLAM eq. 1) at every query point.

    The sums run over the usable points among the ``max_neighbours`` nearest reference
    points within ``radius`` (one bounded k-nearest search, then the sums, in one
    compiled loop).
    Weights are taken relative to the nearest neighbour, ``exp(-(d^2 - d_0^2)/h^2)``:
    the ratio I(x) is unchanged, but far queries do not underflow to 0 / 0.
    """
    queries = np.ascontiguousarray(queries, dtype=float).reshape(-1, 2)
    index = model.index
    value, normal, defined, count, mean, nearest = implicit_surface_kernel(
        index.sorted_points, index.bearings, index.directions, index.order, model.normals,
        model.usable, model.offset, queries, h, radius, max(1, min(max_neighbours, index.n)),
        max(min_neighbours, 1))
    return SurfaceSample(value, normal, defined, count, mean, nearest)


@numba.njit(cache=True, nogil=True)
def implicit_surface_kernel(sorted_points: np.ndarray, bearings: np.ndarray,
                            directions: np.ndarray, order: np.ndarray, normals: np.ndarray,
                            usable: np.ndarray, offset: np.ndarray, queries: np.ndarray,
                            h: float, radius: float, k: int, min_neighbours: int) -> tuple:
    """Compiled kernel of :func:`implicit_surface` (padded model arrays, sorted index)."""
    m = queries.shape[0]
    n = order.shape[0]
    value = np.zeros(m)
    normal = np.zeros((m, 2))
    defined = np.zeros(m, dtype=np.bool_)
    count = np.zeros(m, dtype=np.int64)
    mean = np.zeros((m, 2))
    nearest = np.full(m, n, dtype=np.int64)
    if m == 0 or n == 0:
        return value, normal, defined, count, mean, nearest
    distance, index = k_nearest_by_bearing(sorted_points, bearings, directions, order,
                                           queries, k, radius)
    for q in range(m):
        first = -1
        for c in range(k):  # neighbours come nearest first: the first usable is nearest
            if usable[index[q, c]]:
                count[q] += 1
                if first < 0:
                    first = c
        if count[q] < min_neighbours:
            continue
        defined[q] = True
        base = distance[q, first] ** 2
        total = plane = mx = my = 0.0
        for c in range(k):
            j = index[q, c]
            if not usable[j]:
                continue
            weight = math.exp((base - distance[q, c] ** 2) / (h * h))
            total += weight
            plane += weight * (queries[q, 0] * normals[j, 0] + queries[q, 1] * normals[j, 1]
                               - offset[j])
            mx += weight * normals[j, 0]
            my += weight * normals[j, 1]
        value[q] = plane / total
        nearest[q] = index[q, first]
        normal[q, 0], normal[q, 1] = normals[nearest[q], 0], normals[nearest[q], 1]
        length = math.hypot(mx, my)
        if length > 0.0:
            mean[q, 0], mean[q, 1] = mx / length, my / length
    return value, normal, defined, count, mean, nearest


@numba.njit(cache=True, nogil=True)
def project_onto_surface(queries: np.ndarray, values: np.ndarray,
                         normals: np.ndarray) -> np.ndarray:
    """Project queries onto the IMLS surface: ``y = x - I(x) n`` (IMLS-SLAM section III-C).

    ``values`` are I(x) and ``normals`` the unit normals to project along (Deschaud
    takes the normal of the nearest reference point, :attr:`SurfaceSample.normal`).
    """
    return queries - values.reshape(-1, 1) * normals


@numba.njit(cache=True, nogil=True)
def planarity(curvature: np.ndarray) -> np.ndarray:
    """Return the 2D planarity ``a_2D = 1 - sqrt(l1 / l2)`` from the curvature.

    ``curvature = l1 / (l1 + l2)`` (see :mod:`laser_odom.core.scan.normals`), so
    ``l1 / l2 = c / (1 - c)``. This is the 2D analogue of Deschaud's
    ``a_2D = (sigma_2 - sigma_3) / sigma_1`` with ``sigma = sqrt(lambda)``: 1 on a
    straight line, 0 on an isotropic blob.
    """
    c = np.minimum(np.maximum(curvature, 0.0), 0.5)
    return 1.0 - np.sqrt(c / np.maximum(1.0 - c, 1e-12))


@numba.njit(cache=True, nogil=True)
def observability_scores(points: np.ndarray, normals: np.ndarray,
                         curvature: np.ndarray) -> np.ndarray:
    """Return the (N, 4) selection scores of IMLS-SLAM section III-B, in 2D.

    Columns: ``a^2 |n . e_x|``, ``a^2 |n . e_y|``, ``a^2 (x cross n)`` and
    ``-a^2 (x cross n)``: how strongly a point's tangent-line distance responds to a
    motion along x, along y, and to a rotation either way (its lever arm).
    """
    a2 = np.square(planarity(curvature))
    scores = np.empty((points.shape[0], 4))
    for i in range(points.shape[0]):
        cross = points[i, 0] * normals[i, 1] - points[i, 1] * normals[i, 0]
        scores[i, 0], scores[i, 1] = a2[i] * abs(normals[i, 0]), a2[i] * abs(normals[i, 1])
        scores[i, 2], scores[i, 3] = a2[i] * cross, -a2[i] * cross
    return scores


def candidate_ranking(model: SurfaceModel) -> np.ndarray:
    """Return each score list's candidates, best first (cached on the model).

    Row ``c`` of the (4, N) result holds the usable points of the model's scan with a
    strictly positive score in column ``c`` of :func:`observability_scores`, by
    decreasing score (ties: lower index first), then -1. Only strictly positive scores
    count: a point on a line through the sensor says nothing about the rotation. The
    ranking depends on the scan alone, so a scan ranks its points once, though it is
    the selecting scan of two matches (forward as the current scan, backward as the
    reference).
    """
    if model.ranking is None:
        model.ranking = _rank_candidates(
            observability_scores(model.points[:-1], model.normals[:-1],
                                 model.curvature[:-1]), model.usable[:-1])
    return model.ranking


@numba.njit(cache=True, nogil=True)
def _rank_candidates(scores: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """Compiled :func:`candidate_ranking` of given scores (a stable sort per column)."""
    count, columns = scores.shape
    ranking = np.full((columns, count), -1, dtype=np.int64)
    candidates = np.empty(count, dtype=np.int64)
    for column in range(columns):
        found = 0
        for i in range(count):
            if usable[i] and scores[i, column] > 0.0:
                candidates[found] = i
                found += 1
        order = np.argsort(-scores[candidates[:found], column], kind='mergesort')
        for rank in range(found):
            ranking[column, rank] = candidates[order[rank]]
    return ranking


def select_on_surface(model: SurfaceModel, ranking: np.ndarray, points: np.ndarray,
                      pose: np.ndarray, per_list: int, h: float, radius: float,
                      max_neighbours: int, min_neighbours: int
                      ) -> tuple[np.ndarray, SurfaceSample]:
    """Select the informative points (IMLS-SLAM section III-B) that reach the surface.

    Lists are filled in turn (x, y, +rotation, -rotation) from ``ranking``
    (:func:`candidate_ranking` of the selecting scan, whose ``points`` are moved by
    ``pose``): each keeps its best ``per_list`` points that an earlier list has not
    taken and that have a surface value of ``model`` within ``radius``. The surface
    is evaluated only where a list looks, a few hundred points, not the whole scan.
    Returns the sorted indices of the selected points and the surface there.
    """
    index = model.index
    selected, value, normal, count, mean, nearest = select_on_surface_kernel(
        index.sorted_points, index.bearings, index.directions, index.order, model.normals,
        model.usable, model.offset, np.ascontiguousarray(points, dtype=float).reshape(-1, 2),
        ranking, np.asarray(pose, dtype=float), per_list, h, radius,
        max(1, min(max_neighbours, index.n)), max(min_neighbours, 1))
    return selected, SurfaceSample(value, normal, np.ones(len(selected), dtype=bool), count,
                                   mean, nearest)


@numba.njit(cache=True, nogil=True)
def select_on_surface_kernel(sorted_points: np.ndarray, bearings: np.ndarray,
                             directions: np.ndarray, order: np.ndarray, normals: np.ndarray,
                             usable: np.ndarray, offset: np.ndarray, points: np.ndarray,
                             ranking: np.ndarray, pose: np.ndarray, per_list: int, h: float,
                             radius: float, k: int, min_neighbours: int) -> tuple:
    """Compiled kernel of :func:`select_on_surface`.

    The lists are filled taking every point not yet evaluated as on the surface; the
    points that this reached are evaluated together (one :func:`implicit_surface_kernel`
    call), and the lists filled again, until they reach no unevaluated point. Then
    every list stopped at its ``per_list``-th point known to be on the surface, so the
    selection is that of the whole scan evaluated. Usually two rounds.
    """
    m = points.shape[0]
    evaluated = np.zeros(m, dtype=np.bool_)
    value = np.zeros(m)
    normal = np.zeros((m, 2))
    defined = np.zeros(m, dtype=np.bool_)
    count = np.zeros(m, dtype=np.int64)
    mean = np.zeros((m, 2))
    nearest = np.full(m, order.shape[0], dtype=np.int64)
    taken = np.zeros(m, dtype=np.bool_)
    wanted = np.empty(m, dtype=np.int64)
    while True:
        taken[:] = False
        unknown = 0
        for column in range(ranking.shape[0]):
            kept = 0
            for rank in range(ranking.shape[1]):
                i = ranking[column, rank]
                if kept >= per_list or i < 0:
                    break
                if taken[i] or (evaluated[i] and not defined[i]):
                    continue
                if not evaluated[i]:
                    wanted[unknown] = i
                    unknown += 1
                taken[i] = True
                kept += 1
        if unknown == 0:
            break
        batch = wanted[:unknown]
        at, along, on, neighbours, mean_at, nearest_at = implicit_surface_kernel(
            sorted_points, bearings, directions, order, normals, usable, offset,
            move_points(pose, points[batch]), h, radius, k, min_neighbours)
        for b in range(unknown):
            i = batch[b]
            evaluated[i], defined[i], value[i], count[i] = True, on[b], at[b], neighbours[b]
            normal[i, 0], normal[i, 1] = along[b, 0], along[b, 1]
            mean[i, 0], mean[i, 1] = mean_at[b, 0], mean_at[b, 1]
            nearest[i] = nearest_at[b]
    selected = np.flatnonzero(taken)
    return (selected, value[selected], normal[selected], count[selected], mean[selected],
            nearest[selected])
