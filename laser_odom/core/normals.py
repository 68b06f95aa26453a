"""Per-point surface normals and curvature of a 2D scan from local covariance.

For each point, the covariance of its neighbourhood (k nearest points, limited to a
radius) has eigenvalues l1 <= l2. The normal is the eigenvector of l1, oriented
towards the sensor, and the curvature is l1 / (l1 + l2) (Pauly et al., "Efficient
simplification of point-sampled surfaces", 2002; used by NICP, Serafin & Grisetti 2015,
and IMLS-SLAM, Deschaud 2018). The 2x2 eigen-problem is solved in closed form for
all points at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from laser_odom.core.scan import ScanPoints


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
    # Imported here: the matchers package imports this module (ICP's information).
    from laser_odom.core.matchers.correspondences import k_nearest
    origin = np.zeros(2) if sensor_origin is None else np.asarray(sensor_origin, float)
    key = ('normals', neighbours, radius, min_neighbours, tuple(origin), extent)
    cached = scan.cache.get(key)
    if cached is not None:
        return cached
    if len(scan) == 0:
        result = normals_from_neighbours(scan, np.zeros((0, 1)), np.zeros((0, 1), dtype=int),
                                         min_neighbours, origin)
    else:
        distance, index = k_nearest(scan.tree, scan.points, neighbours, radius)
        if extent is not None:
            far = distance[:, min_neighbours:]
            far[far > extent] = np.inf
        result = normals_from_neighbours(scan, distance, index, min_neighbours, origin)
    scan.cache[key] = result
    return result


def normals_from_neighbours(scan: ScanPoints, distance: np.ndarray, index: np.ndarray,
                            min_neighbours: int,
                            sensor_origin: np.ndarray | None = None) -> SurfaceNormals:
    """Return normals and curvature from given neighbourhoods (not cached).

    ``distance`` and ``index`` (N, k) are KD-tree query results over the scan's own
    points; an infinite distance marks a missing (or excluded) neighbour. This is the
    computation behind :func:`estimate_normals`, for callers that derive several
    neighbourhoods from one query.
    """
    n = len(scan)
    origin = np.zeros(2) if sensor_origin is None else np.asarray(sensor_origin, float)
    present = np.isfinite(distance)
    count = present.sum(axis=1)
    # Per-coordinate (N, k) arrays and row sums: much faster than 3-D einsums.
    safe_count = np.maximum(count, 1)
    weights = present.astype(float)
    rows = np.minimum(index, n)
    xs = np.append(scan.points[:, 0], 0.0)[rows]
    ys = np.append(scan.points[:, 1], 0.0)[rows]
    mean = np.column_stack(((xs * weights).sum(axis=1) / safe_count,
                            (ys * weights).sum(axis=1) / safe_count))
    dx = (xs - mean[:, 0:1]) * weights
    dy = (ys - mean[:, 1:2]) * weights
    cov = np.empty((n, 2, 2))
    cov[:, 0, 0] = np.einsum('nk,nk->n', dx, dx) / safe_count
    cov[:, 0, 1] = cov[:, 1, 0] = np.einsum('nk,nk->n', dx, dy) / safe_count
    cov[:, 1, 1] = np.einsum('nk,nk->n', dy, dy) / safe_count
    a, b, c = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    half_trace = 0.5 * (a + c)
    spread = np.sqrt(np.square(0.5 * (a - c)) + b * b)
    smallest = np.maximum(half_trace - spread, 0.0)
    total = a + c
    # Direction of the largest eigenvector is 0.5 * atan2(2b, a - c); the normal is
    # perpendicular to it.
    principal = 0.5 * np.arctan2(2.0 * b, a - c)
    normals = np.column_stack((-np.sin(principal), np.cos(principal)))
    towards_sensor = np.einsum('nd,nd->n', normals, origin - scan.points)
    normals[towards_sensor < 0.0] *= -1.0
    with np.errstate(invalid='ignore', divide='ignore'):
        curvature = np.where(total > 0.0, smallest / total, 0.0)
    valid = (count >= min_neighbours) & (total > 0.0)
    normals[~valid] = 0.0
    return SurfaceNormals(normals, curvature, cov, valid, count, mean)
