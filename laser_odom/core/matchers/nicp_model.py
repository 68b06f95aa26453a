"""The NICP error model for 2D scans: extended points, information blocks, pair rules.

Serafin & Grisetti, "NICP: Dense Normal Based Point Cloud Registration", IROS 2015.
Every point becomes an *extended point* ``(p, n)`` (position and surface normal); the
transform acts as ``T (p, n) = (R p + t, R n)`` (Sec. III). A pair (current ``i``,
reference ``j``) has the 4-vector error

    e_ij = [R p_i + t - q_j ; R n_i - m_j]                                  (eq. 2)

weighted by the information ``Omega_j = diag(Omega_p_j, omega_n_j I2)`` of the
reference point (Sec. IV-B): ``Omega_p`` is the inverse of the neighbourhood covariance,
regularised by the sensor noise, so it is strong across a surface and weak along it;
``omega_n`` is large where the surface is flat and its normal well defined, 1 otherwise.
Pairs are kept only when both normals are defined and the points, normals and
curvatures agree (Sec. IV-A). With the pose parameterised as ``[x, y, theta]`` the
Jacobian of ``e`` is

    J = [[1, 0, -(R p)_y], [0, 1, (R p)_x], [0, 0, -(R n)_y], [0, 0, (R n)_x]]

and one Gauss-Newton step solves ``(sum w J^T Omega J) dx = -sum w J^T Omega e``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from laser_odom.core.matchers.correspondences import k_nearest
from laser_odom.core.normals import normals_from_neighbours, SurfaceNormals
from laser_odom.core.scan import ScanPoints


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
    usable_ones: np.ndarray
    orientation_histogram: np.ndarray


def _eigenvalues(covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
    """
    smallest, largest = _eigenvalues(covariance)
    dof = np.maximum(count - 2, 0).astype(float)
    with np.errstate(divide='ignore', invalid='ignore'):
        variance = smallest / (dof * largest)
    return np.where(np.isfinite(variance), np.minimum(variance, 1.0), 1.0)


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
    the reported information uses it; single rows may then be indefinite, sums are not.
    """
    smallest, largest = _eigenvalues(covariance)
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

    One KD-tree query serves both: the matching neighbourhood is its first
    ``neighbours`` columns within ``radius`` (beyond ``min_neighbours`` only within
    ``extent``, see :func:`estimate_normals`), the wider one its first
    ``information_neighbours`` columns within ``information_radius``.
    """
    if len(scan) == 0:
        empty = normals_from_neighbours(scan, np.zeros((0, 1)), np.zeros((0, 1), dtype=int),
                                        settings.min_neighbours)
        return empty, empty
    k = max(settings.neighbours, settings.information_neighbours)
    distance, index = k_nearest(scan.tree, scan.points, k,
                                max(settings.radius, settings.information_radius))
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
    curvature is below ``flat_curvature`` and 1 elsewhere (NICP Sec. IV-B).
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
        log_curvature_usable=log_curvature[index], usable_ones=np.ones(index.size, bool),
        orientation_histogram=histogram)
    scan.cache[key] = surface
    return surface


def pair_rules(reference: NicpSurface, reference_index: np.ndarray, distance: np.ndarray,
               rotated_normals: np.ndarray, log_curvature: np.ndarray,
               current_usable: np.ndarray, max_distance: float, min_normal_cosine: float,
               max_curvature_ratio: float) -> dict[str, np.ndarray]:
    """Return, per rule, which candidate pairs pass it (NICP Sec. IV-A).

    Candidates are current points (their ``rotated_normals`` = R n, ``log_curvature``
    and ``current_usable``) paired with ``reference_index``. A pair is kept when both
    normals are well defined (``normal``), the points are at most ``max_distance``
    apart (``distance``), the normals differ by at most ``acos(min_normal_cosine)``
    (``angle``), and ``|log c_i - log c_j|`` is at most ``max_curvature_ratio``
    (``curvature``): a corner never pairs with a wall.
    """
    ref_normals = reference.normals[reference_index]
    cosine = np.einsum('nd,nd->n', rotated_normals, ref_normals)
    ratio = np.abs(log_curvature - reference.log_curvature[reference_index])
    return {
        'normal': current_usable & reference.usable[reference_index],
        'distance': distance <= max_distance,
        'angle': cosine >= min_normal_cosine,
        'curvature': ratio <= max_curvature_ratio,
    }


def associate(tree: cKDTree, reference: NicpSurface, moved: np.ndarray,
              rotated_normals: np.ndarray, log_curvature: np.ndarray, usable: np.ndarray,
              max_distance: float, min_normal_cosine: float,
              max_curvature_ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Pair current points with their nearest reference points and apply the NICP rules.

    ``moved`` and ``rotated_normals`` are the current points and normals under the
    pose estimate; ``tree`` indexes the reference points. Returns the positions (in
    ``moved``) and the reference indices of the pairs that pass every rule of
    :func:`pair_rules`.
    """
    distance, index = tree.query(moved, k=1, distance_upper_bound=max_distance)
    found = np.flatnonzero(index < tree.n)
    ref_index = index[found]
    rules = pair_rules(reference, ref_index, distance[found], rotated_normals[found],
                       log_curvature[found], usable[found], max_distance,
                       min_normal_cosine, max_curvature_ratio)
    keep = rules['normal'] & rules['distance'] & rules['angle'] & rules['curvature']
    return found[keep], ref_index[keep]


def dense_information(info_point: np.ndarray, info_normal: np.ndarray) -> np.ndarray:
    """Return the (M, 4, 4) block-diagonal information ``diag(Omega_p, omega_n I2)``."""
    omega = np.zeros((info_point.shape[0], 4, 4))
    omega[:, 0, 0] = info_point[:, 0]
    omega[:, 0, 1] = omega[:, 1, 0] = info_point[:, 1]
    omega[:, 1, 1] = info_point[:, 2]
    omega[:, 2, 2] = omega[:, 3, 3] = info_normal
    return omega


def residuals_and_jacobians(pose: np.ndarray, points: np.ndarray, normals: np.ndarray,
                            ref_points: np.ndarray,
                            ref_normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the (M, 4) errors ``e`` of eq. 2 and their (M, 4, 3) Jacobians.

    Dense reference form, used to check :func:`normal_equations` and by the tests.
    """
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, -s], [s, c]])
    rp = points @ rot.T
    rn = normals @ rot.T
    error = np.hstack((rp + pose[:2] - ref_points, rn - ref_normals))
    jac = np.zeros((points.shape[0], 4, 3))
    jac[:, 0, 0] = jac[:, 1, 1] = 1.0
    jac[:, 0, 2], jac[:, 1, 2] = -rp[:, 1], rp[:, 0]
    jac[:, 2, 2], jac[:, 3, 2] = -rn[:, 1], rn[:, 0]
    return error, jac


def chi_squared(point_error: np.ndarray, normal_error: np.ndarray, info_point: np.ndarray,
                info_normal: np.ndarray) -> np.ndarray:
    """Return ``e^T Omega e`` per pair for the block-diagonal NICP information."""
    ex, ey = point_error[:, 0], point_error[:, 1]
    return (info_point[:, 0] * ex * ex + 2.0 * info_point[:, 1] * ex * ey
            + info_point[:, 2] * ey * ey
            + info_normal * np.einsum('nd,nd->n', normal_error, normal_error))


def normal_equations(rotated_points: np.ndarray, rotated_normals: np.ndarray,
                     point_error: np.ndarray, normal_error: np.ndarray,
                     info_point: np.ndarray, info_normal: np.ndarray,
                     weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return ``H = sum w J^T Omega J`` and ``g = sum w J^T Omega e`` (3x3, 3).

    Exploits the sparsity of ``J`` (identity in the translation columns, zeros in the
    normal rows) and of ``Omega`` (block diagonal), so every entry is one weighted
    sum: with ``a = d(Rp)/dtheta`` and ``b = d(Rn)/dtheta = [-(Rn)_y, (Rn)_x]``,
    ``H_tt = Omega_p``, ``H_t,theta = Omega_p a``, ``H_theta,theta = a^T Omega_p a +
    omega_n |b|^2``, ``g_t = Omega_p e_p``, ``g_theta = a^T Omega_p e_p + omega_n b^T e_n``.
    """
    pxx, pxy, pyy = info_point[:, 0], info_point[:, 1], info_point[:, 2]
    ax, ay = -rotated_points[:, 1], rotated_points[:, 0]
    bx, by = -rotated_normals[:, 1], rotated_normals[:, 0]
    oax, oay = pxx * ax + pxy * ay, pxy * ax + pyy * ay
    oex = pxx * point_error[:, 0] + pxy * point_error[:, 1]
    oey = pxy * point_error[:, 0] + pyy * point_error[:, 1]
    terms = np.stack((
        pxx, pxy, pyy, oax, oay,
        ax * oax + ay * oay + info_normal * (bx * bx + by * by),
        oex, oey,
        ax * oex + ay * oey + info_normal * (bx * normal_error[:, 0] + by * normal_error[:, 1]),
    ))
    s = terms @ weights
    hessian = np.array([[s[0], s[1], s[3]], [s[1], s[2], s[4]], [s[3], s[4], s[5]]])
    return hessian, s[6:9].copy()


def is_degenerate(information: np.ndarray, length_scale: float,
                  min_information: float) -> bool:
    """Tell whether some direction of the information is too weak to trust.

    The pipeline's acceptance test (:func:`laser_odom.core.acceptance.
    degenerate_directions`), so that the matcher's flag and the pipeline agree:
    rotation is measured as the arc at the scan's RMS range ``length_scale`` and any
    eigenvalue below ``min_information`` [1/m^2] (a featureless corridor's axis) is weak.
    """
    # Imported here: the acceptance module imports the matcher registry.
    from laser_odom.core.acceptance import degenerate_directions
    return bool(np.any(degenerate_directions(information, length_scale, min_information)[2]))


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
    smooth = (6.0 * hist + 4.0 * (np.roll(hist, 1) + np.roll(hist, -1))
              + np.roll(hist, 2) + np.roll(hist, -2)) / 16.0
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
