"""Per-scan NICP data: normals, curvature, information blocks, orientation histogram.

Serafin & Grisetti, "NICP: Dense Normal Based Point Cloud Registration", IROS 2015,
Sec. IV-B. Every scan point gets a normal and a curvature from its neighbourhood
covariance (:mod:`laser_odom.core.scan.normals`), a 2x2 point information (the inverse of
the regularised neighbourhood covariance: strong across a surface, weak along it) and
a normal weight (strong on flat surfaces). Computed once per scan and cached on it: a
scan is first the current scan of one match, then the reference of the next.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from laser_odom.core.matchers.histograms import wrapped
from laser_odom.core.scan.laser_scan import ScanPoints
from laser_odom.core.scan.normals import (
    eigenvalues_2x2, neighbourhoods, normal_variance, normals_from_neighbours, SurfaceNormals)


@dataclass(frozen=True)
class SurfaceSettings:
    """What a scan's NICP surface depends on (also its cache key)."""

    neighbours: int
    radius: float
    min_neighbours: int
    extent: float
    information_neighbours: int
    information_radius: float
    max_curvature: float
    flat_curvature: float
    point_sigma: float
    tangent_sigma: float
    normal_information: float
    curvature_floor: float
    smooth_points: bool


@dataclass
class NicpSurface:
    """Per-scan NICP data, computed once per scan and cached on it.

    ``usable`` marks points whose normal is well defined; ``index`` lists them.
    ``info_point`` holds the symmetric 2x2 point information as ``[xx, xy, yy]`` per
    point (``info_report`` the same, debiased for the noise of the normals, for the
    information of the result), ``info_normal`` the scalar weight of the normal
    block, ``log_curvature`` the log of the (floored) curvature. The ``*_usable``
    arrays are the same data restricted to the usable points, ready for the
    per-iteration work.
    """

    points: np.ndarray
    normals: np.ndarray
    log_curvature: np.ndarray
    usable: np.ndarray
    info_point: np.ndarray
    info_report: np.ndarray
    info_normal: np.ndarray
    index: np.ndarray
    points_usable: np.ndarray
    normals_usable: np.ndarray
    log_curvature_usable: np.ndarray
    orientation_histogram: np.ndarray


def point_information(covariance: np.ndarray, normals: np.ndarray, flat: np.ndarray,
                      point_sigma: float, tangent_sigma: float,
                      normal_var: np.ndarray | None = None) -> np.ndarray:
    """Return the point information ``C_reg^-1`` as ``[xx, xy, yy]`` rows.

    NICP (Sec. IV-B, and its reference implementation) weighs the point error by the
    inverse of the neighbourhood covariance ``C`` in the eigenbasis of ``C``: across
    the surface (along the normal ``n``, eigenvalue ``l1``) the position is known to
    the noise, along it (tangent ``t``, eigenvalue ``l2``) only to the spread of the
    neighbours. The covariance is regularised as
    ``C_reg = C + sigma^2 I + [flat] tau^2 t t^T``: ``sigma^2`` (range noise) bounds the
    weight of noise-free, collinear neighbourhoods, and on flat surfaces ``tau^2``
    says that a wall sample does not tell where along the wall a point lies (NICP's
    flat information is ``diag(1000, 0.001)`` in the same basis). Sliding along a wall
    is then nearly free, as it is for the scene; corners and curved surfaces keep
    their along-surface information. In closed form,
    ``C_reg^-1 = a n n^T + b t t^T``, ``a = 1 / (l1 + sigma^2)``,
    ``b = 1 / (l2 + sigma^2 + [flat] tau^2)``.

    With ``normal_var`` (the variance ``s^2`` of each normal's direction) the result is
    debiased for the noise of the normals: a noisy ``n`` leaks ``s^2 (a - b)`` of the
    across-surface weight into the along-surface direction, ``E[n n^T] = n0 n0^T +
    s^2 (t0 t0^T - n0 n0^T)``, which summed over a corridor's walls would claim that
    the corridor's axis is observed. Subtracting the expected leak,
    ``a' = a + s^2 (a - b)``, ``b' = b - s^2 (a - b)``, gives an unbiased estimate of
    the information the surfaces really hold (errors-in-variables correction). Only
    the reported information uses it; single rows may then be indefinite (the matcher
    projects the summed information back onto the positive semi-definite cone).
    """
    smallest, largest = eigenvalues_2x2(covariance)
    reg = point_sigma * point_sigma
    across = 1.0 / (smallest + reg)
    along = 1.0 / (largest + reg + np.where(flat, tangent_sigma ** 2, 0.0))
    if normal_var is not None:
        leak = normal_var * (across - along)
        across, along = across + leak, along - leak
    nx, ny = normals[:, 0], normals[:, 1]
    diff = across - along
    # a n n^T + b t t^T with t = n rotated by 90 degrees: b I + (a - b) n n^T.
    return np.column_stack((along + diff * nx * nx, diff * nx * ny, along + diff * ny * ny))


def _neighbourhoods(scan: ScanPoints,
                    settings: SurfaceSettings) -> tuple[SurfaceNormals, SurfaceNormals]:
    """Return the matching normals and the wider ones behind the information.

    One k-nearest search serves both: the matching neighbourhood is its first
    ``neighbours`` columns within ``radius`` (beyond ``min_neighbours`` only within
    ``extent``, see :func:`estimate_normals`), the wider one its first
    ``information_neighbours`` columns within ``information_radius``.
    """
    if len(scan) == 0:
        empty = normals_from_neighbours(scan, np.zeros((0, 1)), np.zeros((0, 1), dtype=int),
                                        settings.min_neighbours)
        return empty, empty
    k = max(settings.neighbours, settings.information_neighbours)
    distance, index = neighbourhoods(scan, k, max(settings.radius,
                                                  settings.information_radius))
    near = distance[:, :settings.neighbours].copy()
    near[near > settings.radius] = np.inf
    if settings.extent > 0.0:
        far = near[:, settings.min_neighbours:]
        far[far > settings.extent] = np.inf
    wide = distance[:, :settings.information_neighbours].copy()
    wide[wide > settings.information_radius] = np.inf
    return (normals_from_neighbours(scan, near, index[:, :settings.neighbours],
                                    settings.min_neighbours),
            normals_from_neighbours(scan, wide, index[:, :settings.information_neighbours],
                                    settings.min_neighbours))


def nicp_surface(scan: ScanPoints, settings: SurfaceSettings) -> NicpSurface:
    """Return the (cached) NICP surface of a scan: normals, curvature, information.

    A normal is well defined when its neighbourhood holds ``min_neighbours`` points and
    the curvature (smallest over summed eigenvalue, at most 0.5 in 2D) is at most
    ``max_curvature``. The normal block weight is ``normal_information`` where the
    curvature is below ``flat_curvature`` and 1 elsewhere (NICP Sec. IV-B). With
    ``smooth_points`` each flat point is moved onto the line fitted to its
    neighbourhood (its total-least-squares surface estimate), which removes most of
    the range noise from the point error; the search index keeps the measured points.
    """
    key = ('nicp_surface', settings)
    cached = scan.cache.get(key)
    if cached is not None:
        return cached
    est, wide = _neighbourhoods(scan, settings)
    usable = est.valid & (est.curvature <= settings.max_curvature)
    log_curvature = np.log(np.maximum(est.curvature, settings.curvature_floor))
    flat = usable & (est.curvature < settings.flat_curvature)
    info_point = point_information(est.covariance, est.normals, flat, settings.point_sigma,
                                   settings.tangent_sigma)
    # The information of the result rests on smoother normals where the wider
    # neighbourhood exists, on the matching ones (sparse points) elsewhere; both are
    # debiased for the noise of the normals.
    info_report = np.where(
        wide.valid[:, None],
        point_information(wide.covariance, wide.normals,
                          wide.valid & (wide.curvature < settings.flat_curvature),
                          settings.point_sigma, settings.tangent_sigma,
                          normal_variance(wide.covariance, wide.count)),
        point_information(est.covariance, est.normals, flat, settings.point_sigma,
                          settings.tangent_sigma, normal_variance(est.covariance, est.count)))
    info_normal = np.where(flat, settings.normal_information, 1.0)
    points = scan.points
    if settings.smooth_points:
        # Flat points move onto their fitted line: q - n n^T (q - centroid).
        offset = np.einsum('nd,nd->n', points - est.centroid, est.normals)
        points = points - np.where(flat, offset, 0.0)[:, None] * est.normals
    index = np.flatnonzero(usable)
    histogram = orientation_histogram(est.normals[index], scan.ranges[index])
    surface = NicpSurface(
        points=points, normals=est.normals, log_curvature=log_curvature,
        usable=usable, info_point=info_point, info_report=info_report,
        info_normal=info_normal, index=index,
        points_usable=points[index], normals_usable=est.normals[index],
        log_curvature_usable=log_curvature[index], orientation_histogram=histogram)
    scan.cache[key] = surface
    return surface


HISTOGRAM_BINS = 360
"""Bins of the normal orientation histogram (1 degree each)."""


def orientation_histogram(normals: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """Return the smoothed, normalised histogram of normal directions of a scan.

    Each normal counts with its beam's range, roughly the length of surface the beam
    covers, so a far wall is not outweighed by a near one with denser points. A
    circular [1, 4, 6, 4, 1] / 16 kernel (binomial, about a 1-degree sigma) smooths
    the quantisation.
    """
    angles = np.arctan2(normals[:, 1], normals[:, 0])
    bins = np.floor((angles + np.pi) * (HISTOGRAM_BINS / (2.0 * np.pi))).astype(int)
    hist = np.bincount(np.clip(bins, 0, HISTOGRAM_BINS - 1), weights=ranges,
                       minlength=HISTOGRAM_BINS).astype(float)
    padded = wrapped(hist, 2)
    smooth = (6.0 * hist + 4.0 * (padded[1:-3] + padded[3:-1])
              + padded[:-4] + padded[4:]) / 16.0
    norm = float(np.linalg.norm(smooth))
    return smooth / norm if norm > 0.0 else smooth


def rotation_seed(reference: NicpSurface, current: NicpSurface, guess: float,
                  window: float) -> float:
    """Return the rotation within ``guess +- window`` that best aligns the normal histograms.

    Rotating the sensor by ``theta`` shifts every normal direction by ``theta`` and
    translation changes none, so the circular cross-correlation of the two orientation
    histograms peaks at the rotation between the scans (Weiss, Wetzler & von Puttkamer,
    "Keeping track of position and orientation of moving indoor systems by correlation
    of range-finder scans", IROS 1994). The peak is refined by a parabola through the
    best bin and its neighbours. Used to restart a match whose rotation guess was poor.
    """
    width = 2.0 * np.pi / HISTOGRAM_BINS
    # Circular cross-correlation of all shifts at once, by FFT.
    spectrum = np.fft.rfft(reference.orientation_histogram) * np.conj(
        np.fft.rfft(current.orientation_histogram))
    correlation = np.fft.irfft(spectrum, HISTOGRAM_BINS)
    centre = int(round(guess / width))
    half = max(1, int(np.ceil(window / width)))
    shifts = np.arange(centre - half - 1, centre + half + 2)
    score = correlation[shifts % HISTOGRAM_BINS]
    best = int(np.argmax(score[1:-1])) + 1
    left, mid, right = score[best - 1], score[best], score[best + 1]
    curvature = left - 2.0 * mid + right
    offset = 0.5 * (left - right) / curvature if curvature < 0.0 else 0.0
    return float((shifts[best] + offset) * width)
