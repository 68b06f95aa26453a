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

import numpy as np
from scipy.spatial import cKDTree

from laser_odom.core.normals import estimate_normals
from laser_odom.core.scan import ScanPoints


@dataclass
class SurfaceModel:
    """A scan's points and normals, padded for masked KD-tree lookups.

    Row ``n`` of ``points`` and ``normals`` is a zero pad that missing KD-tree
    neighbours (index ``tree.n``) point to; ``usable[n]`` is False, as is ``usable``
    of every point without a well-defined normal. Derived once: ``offset`` is
    ``p_i . n_i`` (the tangent-line distance is ``x . n_i - offset_i``), ``normal_x``
    and ``normal_y`` the normal components, ``curvature`` padded with 0.5 (no
    planarity).
    """

    tree: cKDTree
    points: np.ndarray
    normals: np.ndarray
    usable: np.ndarray
    curvature: np.ndarray
    offset: np.ndarray = field(init=False)
    normal_x: np.ndarray = field(init=False)
    normal_y: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        """Precompute the tangent-line offsets and contiguous normal components."""
        self.offset = np.einsum('nd,nd->n', self.points, self.normals)
        self.normal_x = np.ascontiguousarray(self.normals[:, 0])
        self.normal_y = np.ascontiguousarray(self.normals[:, 1])


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

    def subset(self, keep: np.ndarray) -> SurfaceSample:
        """Return the sample of the queries selected by ``keep`` (mask or indices)."""
        return SurfaceSample(self.value[keep], self.normal[keep], self.defined[keep],
                             self.count[keep], self.mean_normal[keep], self.nearest[keep])


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
        tree=scan.tree,
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
    return SurfaceModel(cKDTree(points), np.vstack((points, pad)), np.vstack((normals, pad)),
                        np.append(ok, False), np.zeros(n + 1))


def implicit_surface(model: SurfaceModel, queries: np.ndarray, h: float, radius: float,
                     max_neighbours: int, min_neighbours: int) -> SurfaceSample:
    """Evaluate the IMLS function I(x) (IMLS-SLAM eq. 1) at every query point.

    The sums run over the ``max_neighbours`` nearest usable reference points within
    ``radius`` (one bounded KD-tree query, then masked sums; no per-point loop).
    Weights are taken relative to the nearest neighbour, ``exp(-(d^2 - d_0^2)/h^2)``:
    the ratio I(x) is unchanged, but far queries do not underflow to 0 / 0.
    """
    m = queries.shape[0]
    n = model.tree.n
    if m == 0 or n == 0:
        return SurfaceSample(np.zeros(m), np.zeros((m, 2)), np.zeros(m, dtype=bool),
                             np.zeros(m, dtype=int), np.zeros((m, 2)), np.full(m, n))
    k = max(1, min(max_neighbours, n))
    distance, index = model.tree.query(queries, k=k, distance_upper_bound=radius)
    if k == 1:
        distance, index = distance[:, None], index[:, None]
    present = model.usable[index]
    count = np.count_nonzero(present, axis=1)
    defined = count >= max(min_neighbours, 1)
    squared = np.where(present, distance * distance, np.inf)
    nearest = np.argmin(squared, axis=1)
    rows = np.arange(m)
    with np.errstate(invalid='ignore'):
        weights = np.exp((squared[rows, nearest][:, None] - squared) / (h * h))
    weights[~defined] = 0.0
    weights[:, 0][~defined] = 1.0        # keeps 0 / 0 out of undefined rows
    plane = (queries[:, 0:1] * model.normal_x[index] + queries[:, 1:2] * model.normal_y[index]
             - model.offset[index])
    value = np.einsum('mk,mk->m', weights, plane) / weights.sum(axis=1)
    value[~defined] = 0.0
    nearest_index = np.where(defined, index[rows, nearest], n)
    normal = model.normals[nearest_index]
    mean = np.column_stack((np.einsum('mk,mk->m', weights, model.normal_x[index]),
                            np.einsum('mk,mk->m', weights, model.normal_y[index])))
    length = np.hypot(mean[:, 0], mean[:, 1])
    mean = np.where(defined[:, None] & (length[:, None] > 0.0),
                    mean / np.maximum(length, 1e-300)[:, None], 0.0)
    return SurfaceSample(value, normal, defined, count, mean, nearest_index)


def project_onto_surface(queries: np.ndarray, values: np.ndarray,
                         normals: np.ndarray) -> np.ndarray:
    """Project queries onto the IMLS surface: ``y = x - I(x) n`` (IMLS-SLAM section III-C).

    ``values`` are I(x) and ``normals`` the unit normals to project along (Deschaud
    takes the normal of the nearest reference point, :attr:`SurfaceSample.normal`).
    """
    return queries - values[:, None] * normals


def planarity(curvature: np.ndarray) -> np.ndarray:
    """Return the 2D planarity ``a_2D = 1 - sqrt(l1 / l2)`` from the curvature.

    ``curvature = l1 / (l1 + l2)`` (see :mod:`laser_odom.core.normals`), so
    ``l1 / l2 = c / (1 - c)``. This is the 2D analogue of Deschaud's
    ``a_2D = (sigma_2 - sigma_3) / sigma_1`` with ``sigma = sqrt(lambda)``: 1 on a
    straight line, 0 on an isotropic blob.
    """
    c = np.clip(curvature, 0.0, 0.5)
    return 1.0 - np.sqrt(c / np.maximum(1.0 - c, 1e-12))


def observability_scores(points: np.ndarray, normals: np.ndarray,
                         curvature: np.ndarray) -> np.ndarray:
    """Return the (N, 4) selection scores of IMLS-SLAM section III-B, in 2D.

    Columns: ``a^2 |n . e_x|``, ``a^2 |n . e_y|``, ``a^2 (x cross n)`` and
    ``-a^2 (x cross n)``: how strongly a point's tangent-line distance responds to a
    motion along x, along y, and to a rotation either way (its lever arm).
    """
    a2 = np.square(planarity(curvature))
    cross = points[:, 0] * normals[:, 1] - points[:, 1] * normals[:, 0]
    return np.column_stack((a2 * np.abs(normals[:, 0]), a2 * np.abs(normals[:, 1]),
                            a2 * cross, -a2 * cross))


def select_informative(scores: np.ndarray, candidates: np.ndarray,
                       per_list: int) -> np.ndarray:
    """Keep the best ``per_list`` candidates of each score column, without duplicates.

    Lists are filled in turn (x, y, +rotation, -rotation); a point already taken by an
    earlier list is skipped, so each list still contributes up to ``per_list`` distinct
    points. Only strictly positive scores count (a point on a line through the sensor
    says nothing about the rotation). Returns sorted point indices.
    """
    taken = np.zeros(scores.shape[0], dtype=bool)
    allowed = np.asarray(candidates, dtype=bool)
    for column in range(scores.shape[1]):
        score = np.where(allowed & ~taken & (scores[:, column] > 0.0),
                         scores[:, column], -np.inf)
        count = min(per_list, int(np.count_nonzero(np.isfinite(score))))
        if count == 0:
            continue
        best = np.argpartition(-score, count - 1)[:count]
        taken[best] = True
    return np.flatnonzero(taken)
