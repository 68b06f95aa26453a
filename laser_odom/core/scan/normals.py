"""Per-point surface normals and curvature of a 2D scan from local covariance.

For each point, the covariance of its neighbourhood (k nearest points, limited to a
radius) has eigenvalues l1 <= l2. The normal is the eigenvector of l1, oriented
towards the sensor, and the curvature is l1 / (l1 + l2) (Pauly et al., "Efficient
simplification of point-sampled surfaces", 2002; used by NICP, Serafin & Grisetti 2015,
and IMLS-SLAM, Deschaud 2018). The 2x2 eigen-problem is solved in closed form for
every point in one compiled loop.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numba
import numpy as np

from laser_odom.core.scan.laser_scan import ScanPoints


@dataclass
class SurfaceNormals:
    """Normals (N, 2), curvature (N,), neighbourhood covariance (N, 2, 2), validity (N,).

    ``count`` (N,) is the size of each neighbourhood (the point included): how many
    points the covariance, hence the normal's precision, rests on. ``centroid`` (N, 2)
    is the neighbourhood mean: with the normal it is the fitted local line.
    """

    normals: np.ndarray
    curvature: np.ndarray
    covariance: np.ndarray
    valid: np.ndarray
    count: np.ndarray | None = None
    centroid: np.ndarray | None = None


def estimate_normals(scan: ScanPoints, neighbours: int = 10, radius: float = 0.3,
                     min_neighbours: int = 4,
                     sensor_origin: np.ndarray | None = None,
                     extent: float | None = None) -> SurfaceNormals:
    """Estimate normals and curvature of every point of ``scan`` (cached per scan).

    A point whose neighbourhood (itself included) holds fewer than ``min_neighbours``
    points within ``radius`` has no well-defined normal: ``valid`` is False and its
    normal is zero. Normals point towards ``sensor_origin`` (default: the origin of the
    scan's frame).

    ``extent`` (optional) adapts the neighbourhood to the sampling density: the
    ``min_neighbours`` nearest points (within ``radius``) always count, further ones
    (up to ``neighbours``) only when within ``extent``. Where the scan is dense the
    normal then rests on all points of a fixed stretch of surface (range noise
    averages out); where it is sparse, on the few nearest ones (a wide neighbourhood
    would span corners and discontinuities).
    """
    origin = np.zeros(2) if sensor_origin is None else np.asarray(sensor_origin, float)
    key = ('normals', neighbours, radius, min_neighbours, tuple(origin), extent)
    cached = scan.cache.get(key)
    if cached is not None:
        return cached
    if len(scan) == 0:
        result = normals_from_neighbours(scan, np.zeros((0, 1)), np.zeros((0, 1), dtype=int),
                                         min_neighbours, origin)
    else:
        distance, index = neighbourhoods(scan, neighbours, radius)
        if extent is not None:
            distance = distance.copy()  # the neighbourhoods are shared through the cache
            far = distance[:, min_neighbours:]
            far[far > extent] = np.inf
        result = normals_from_neighbours(scan, distance, index, min_neighbours, origin)
    scan.cache[key] = result
    return result


def neighbourhoods(scan: ScanPoints, neighbours: int,
                   radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Return the ``neighbours`` nearest points within ``radius`` of every scan point.

    Distances and indices (N, k), nearest first, as :meth:`BearingIndex.k_nearest`
    gives them; cached per scan and radius, so estimates of several neighbourhood
    sizes (a matcher's normals and the smoother ones behind its information) share one
    search: the k nearest are the first k columns of a larger query. A caller that
    will want several sizes asks for the largest first.
    """
    key = ('neighbourhoods', float(radius))
    cached = scan.cache.get(key)
    if cached is None or cached[0].shape[1] < neighbours:
        cached = scan.bearing_index.k_nearest(scan.points, neighbours, radius)
        scan.cache[key] = cached
    return cached[0][:, :neighbours], cached[1][:, :neighbours]


def normals_from_neighbours(scan: ScanPoints, distance: np.ndarray, index: np.ndarray,
                            min_neighbours: int,
                            sensor_origin: np.ndarray | None = None) -> SurfaceNormals:
    """Return normals and curvature from given neighbourhoods (not cached).

    ``distance`` and ``index`` (N, k) are k-nearest results over the scan's own
    points; an infinite distance marks a missing (or excluded) neighbour. This is the
    computation behind :func:`estimate_normals`, for callers that derive several
    neighbourhoods from one search.
    """
    origin = np.zeros(2) if sensor_origin is None else np.asarray(sensor_origin, float)
    normals, curvature, covariance, valid, count, centroid = _normals_kernel(
        np.ascontiguousarray(scan.points, dtype=float).reshape(-1, 2),
        np.ascontiguousarray(distance, dtype=float),
        np.ascontiguousarray(index, dtype=np.int64), int(min_neighbours), origin)
    return SurfaceNormals(normals, curvature, covariance, valid, count, centroid)


@numba.njit(cache=True, nogil=True)
def _normals_kernel(points: np.ndarray, distance: np.ndarray, index: np.ndarray,
                    min_neighbours: int, origin: np.ndarray) -> tuple:
    """Compiled kernel of :func:`normals_from_neighbours`, one point at a time.

    The 2x2 covariance ``[[a, b], [b, c]]`` has eigenvalues ``(a + c) / 2 -+
    sqrt(((a - c) / 2)^2 + b^2)``; its largest eigenvector lies at ``atan2(2b, a - c) /
    2`` and the normal is perpendicular to it, turned towards the sensor.
    """
    n = points.shape[0]
    normals = np.zeros((n, 2))
    curvature = np.zeros(n)
    covariance = np.zeros((n, 2, 2))
    valid = np.zeros(n, dtype=np.bool_)
    count = np.zeros(n, dtype=np.int64)
    centroid = np.zeros((n, 2))
    for i in range(n):
        sx = sy = 0.0
        for c in range(index.shape[1]):
            if np.isfinite(distance[i, c]):
                count[i] += 1
                sx += points[index[i, c], 0]
                sy += points[index[i, c], 1]
        size = max(count[i], 1)
        mx, my = sx / size, sy / size
        a = b = c2 = 0.0
        for c in range(index.shape[1]):
            if np.isfinite(distance[i, c]):
                dx, dy = points[index[i, c], 0] - mx, points[index[i, c], 1] - my
                a += dx * dx
                b += dx * dy
                c2 += dy * dy
        a, b, c2 = a / size, b / size, c2 / size
        centroid[i, 0], centroid[i, 1] = mx, my
        covariance[i, 0, 0], covariance[i, 0, 1] = a, b
        covariance[i, 1, 0], covariance[i, 1, 1] = b, c2
        total = a + c2
        spread = math.sqrt((0.5 * (a - c2)) ** 2 + b * b)
        smallest = max(0.5 * total - spread, 0.0)
        curvature[i] = smallest / total if total > 0.0 else 0.0
        valid[i] = count[i] >= min_neighbours and total > 0.0
        if not valid[i]:
            continue
        principal = 0.5 * math.atan2(2.0 * b, a - c2)
        nx, ny = -math.sin(principal), math.cos(principal)
        if nx * (origin[0] - points[i, 0]) + ny * (origin[1] - points[i, 1]) < 0.0:
            nx, ny = -nx, -ny
        normals[i, 0], normals[i, 1] = nx, ny
    return normals, curvature, covariance, valid, count, centroid


def eigenvalues_2x2(covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the smallest and largest eigenvalue of (N, 2, 2) symmetric matrices."""
    a, b, c = covariance[:, 0, 0], covariance[:, 0, 1], covariance[:, 1, 1]
    half_trace = 0.5 * (a + c)
    spread = np.sqrt(np.square(0.5 * (a - c)) + b * b)
    return np.maximum(half_trace - spread, 0.0), half_trace + spread


def normal_variance(covariance: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Return the variance [rad^2] of each estimated normal direction.

    A line fitted to ``k`` points with across-line scatter ``l1`` and along-line
    variance ``l2`` has a slope variance ``l1 / ((k - 2) l2)`` (least squares, with
    the residual variance ``k l1 / (k - 2)``). Capped at 1 (no direction at all).
    Summed over a corridor's walls, this noise would pose as information along the
    axis; ``nicp``'s point information and ``imls``'s information remove it
    (:func:`.matchers.information.debiased_point_to_line_information`).
    """
    smallest, largest = eigenvalues_2x2(covariance)
    dof = np.maximum(count - 2, 0).astype(float)
    with np.errstate(divide='ignore', invalid='ignore'):
        variance = smallest / (dof * largest)
    return np.where(np.isfinite(variance), np.minimum(variance, 1.0), 1.0)
