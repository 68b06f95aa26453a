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
    points the covariance, hence the normal's precision, rests on.
    """

    normals: np.ndarray
    curvature: np.ndarray
    covariance: np.ndarray
    valid: np.ndarray
    count: np.ndarray | None = None


def estimate_normals(scan: ScanPoints, neighbours: int = 10, radius: float = 0.3,
                     min_neighbours: int = 4,
                     sensor_origin: np.ndarray | None = None) -> SurfaceNormals:
    """Estimate normals and curvature of every point of ``scan`` (cached per scan).

    A point whose neighbourhood (itself included) holds fewer than ``min_neighbours``
    points within ``radius`` has no well-defined normal: ``valid`` is False and its
    normal is zero. Normals point towards ``sensor_origin`` (default: the origin of the
    scan's frame).
    """
    # Imported here: the matchers package imports this module (ICP's information).
    from laser_odom.core.matchers.correspondences import k_nearest
    origin = np.zeros(2) if sensor_origin is None else np.asarray(sensor_origin, float)
    key = ('normals', neighbours, radius, min_neighbours, tuple(origin))
    cached = scan.cache.get(key)
    if cached is not None:
        return cached
    n = len(scan)
    if n == 0:
        result = SurfaceNormals(np.zeros((0, 2)), np.zeros(0), np.zeros((0, 2, 2)),
                                np.zeros(0, dtype=bool), np.zeros(0, dtype=int))
        scan.cache[key] = result
        return result
    distance, index = k_nearest(scan.tree, scan.points, neighbours, radius)
    present = np.isfinite(distance)
    count = present.sum(axis=1)
    padded = np.vstack((scan.points, np.zeros((1, 2))))
    nbrs = padded[np.minimum(index, n)]
    weights = present.astype(float)
    safe_count = np.maximum(count, 1)[:, None]
    mean = np.einsum('nk,nkd->nd', weights, nbrs) / safe_count
    centred = (nbrs - mean[:, None, :]) * weights[:, :, None]
    cov = np.einsum('nki,nkj->nij', centred, centred) / safe_count[:, :, None]
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
    result = SurfaceNormals(normals, curvature, cov, valid, count)
    scan.cache[key] = result
    return result
