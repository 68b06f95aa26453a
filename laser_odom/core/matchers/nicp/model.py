"""The NICP error model for 2D scans: extended points, pair rules, normal equations.

Serafin & Grisetti, "NICP: Dense Normal Based Point Cloud Registration", IROS 2015.
Every point becomes an *extended point* ``(p, n)`` (position and surface normal); the
transform acts as ``T (p, n) = (R p + t, R n)`` (Sec. III). A pair (current ``i``,
reference ``j``) has the 4-vector error

    e_ij = [R p_i + t - q_j ; R n_i - m_j]                                  (eq. 2)

weighted by the information ``Omega_j = diag(Omega_p_j, omega_n_j I2)`` of the
reference point (Sec. IV-B, built per scan in :mod:`.nicp.surface`): ``Omega_p`` is the
inverse of the regularised neighbourhood covariance, strong across a surface and weak
along it; ``omega_n`` is large where the surface is flat and its normal well defined,
1 otherwise.
Pairs are kept only when both normals are defined and the points, normals and
curvatures agree (Sec. IV-A). With the pose parameterised as ``[x, y, theta]`` the
Jacobian of ``e`` is

    J = [[1, 0, -(R p)_y], [0, 1, (R p)_x], [0, 0, -(R n)_y], [0, 0, (R n)_x]]

and one Gauss-Newton step solves ``(sum w J^T Omega J) dx = -sum w J^T Omega e``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from laser_odom.core.matchers.nicp.surface import NicpSurface
from laser_odom.core.matchers.robust import kernel_weights
from laser_odom.core.scan.nearest import BearingIndex, nearest_by_bearing
from laser_odom.core.se2 import move_points
from laser_odom.core.uncertainty.degeneracy import degenerate_directions


RULES = ('normal', 'distance', 'angle', 'curvature')
"""The NICP pair rules (Sec. IV-A), in the column order of :func:`rule_table`."""


@numba.njit(cache=True, nogil=True)
def rule_table(ref_normals: np.ndarray, ref_log_curvature: np.ndarray, ref_usable: np.ndarray,
               reference_index: np.ndarray, distance: np.ndarray,
               rotated_normals: np.ndarray, log_curvature: np.ndarray,
               current_usable: np.ndarray, max_distance: float, min_normal_cosine: float,
               max_curvature_ratio: float) -> np.ndarray:
    """Return (M, 4) booleans: which candidate pair passes which rule of :data:`RULES`.

    Candidates are current points (their ``rotated_normals`` = R n, ``log_curvature``
    and ``current_usable``) paired with ``reference_index``. A pair is kept when both
    normals are well defined (``normal``), the points are at most ``max_distance``
    apart (``distance``), the normals differ by at most ``acos(min_normal_cosine)``
    (``angle``), and ``|log c_i - log c_j|`` is at most ``max_curvature_ratio``
    (``curvature``): a corner never pairs with a wall.
    """
    count = reference_index.shape[0]
    table = np.empty((count, 4), dtype=np.bool_)
    for m in range(count):
        j = reference_index[m]
        cosine = (rotated_normals[m, 0] * ref_normals[j, 0]
                  + rotated_normals[m, 1] * ref_normals[j, 1])
        table[m, 0] = current_usable[m] and ref_usable[j]
        table[m, 1] = distance[m] <= max_distance
        table[m, 2] = cosine >= min_normal_cosine
        table[m, 3] = abs(log_curvature[m] - ref_log_curvature[j]) <= max_curvature_ratio
    return table


def pair_rules(reference: NicpSurface, reference_index: np.ndarray, distance: np.ndarray,
               rotated_normals: np.ndarray, log_curvature: np.ndarray,
               current_usable: np.ndarray, max_distance: float, min_normal_cosine: float,
               max_curvature_ratio: float) -> dict[str, np.ndarray]:
    """Return, per rule of :data:`RULES`, which candidate pairs pass it (NICP Sec. IV-A)."""
    table = rule_table(reference.normals, reference.log_curvature, reference.usable,
                       np.asarray(reference_index, dtype=np.int64),
                       np.asarray(distance, dtype=float), np.asarray(rotated_normals, float),
                       np.asarray(log_curvature, dtype=float),
                       np.asarray(current_usable, dtype=np.bool_), max_distance,
                       min_normal_cosine, max_curvature_ratio)
    return {rule: table[:, column] for column, rule in enumerate(RULES)}


@numba.njit(cache=True, nogil=True)
def _associate(sorted_points: np.ndarray, bearings: np.ndarray, directions: np.ndarray,
               order: np.ndarray, ref_normals: np.ndarray, ref_log_curvature: np.ndarray,
               ref_usable: np.ndarray, moved: np.ndarray, rotated_normals: np.ndarray,
               log_curvature: np.ndarray, usable: np.ndarray, max_distance: float,
               min_normal_cosine: float, max_curvature_ratio: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Compiled kernel of :func:`associate` (the reference index's arrays unpacked)."""
    distance, nearest = nearest_by_bearing(sorted_points, bearings, directions, order, moved,
                                           max_distance,
                                           np.full(moved.shape[0], -1, dtype=np.int64))
    found = np.flatnonzero(nearest < order.shape[0])
    table = rule_table(ref_normals, ref_log_curvature, ref_usable, nearest[found],
                       distance[found], rotated_normals[found], log_curvature[found],
                       usable[found], max_distance, min_normal_cosine, max_curvature_ratio)
    keep = np.empty(found.shape[0], dtype=np.bool_)
    for m in range(found.shape[0]):
        keep[m] = table[m, 0] and table[m, 1] and table[m, 2] and table[m, 3]
    return found[keep], nearest[found][keep]


def associate(index: BearingIndex, reference: NicpSurface, moved: np.ndarray,
              rotated_normals: np.ndarray, log_curvature: np.ndarray, usable: np.ndarray,
              max_distance: float, min_normal_cosine: float,
              max_curvature_ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Pair current points with their nearest reference points and apply the NICP rules.

    The nearest reference point is searched among the measured points (``index``);
    the errors then use the reference surface's (possibly smoothed) points.

    ``moved`` and ``rotated_normals`` are the current points and normals under the
    pose estimate; ``index`` indexes the reference points. Returns the positions (in
    ``moved``) and the reference indices of the pairs that pass every rule of
    :func:`rule_table`.
    """
    return _associate(index.sorted_points, index.bearings, index.directions, index.order,
                      reference.normals, reference.log_curvature, reference.usable,
                      np.ascontiguousarray(moved, dtype=float),
                      np.ascontiguousarray(rotated_normals, dtype=float),
                      np.asarray(log_curvature, dtype=float),
                      np.asarray(usable, dtype=np.bool_), max_distance, min_normal_cosine,
                      max_curvature_ratio)


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


@numba.njit(cache=True, nogil=True)
def chi_squared(point_error: np.ndarray, normal_error: np.ndarray, info_point: np.ndarray,
                info_normal: np.ndarray) -> np.ndarray:
    """Return ``e^T Omega e`` per pair for the block-diagonal NICP information."""
    count = point_error.shape[0]
    chi2 = np.empty(count)
    for m in range(count):
        ex, ey = point_error[m, 0], point_error[m, 1]
        chi2[m] = (info_point[m, 0] * ex * ex + 2.0 * info_point[m, 1] * ex * ey
                   + info_point[m, 2] * ey * ey
                   + info_normal[m] * (normal_error[m, 0] ** 2 + normal_error[m, 1] ** 2))
    return chi2


@numba.njit(cache=True, nogil=True)
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
    s = np.zeros(9)
    for m in range(rotated_points.shape[0]):
        w = weights[m]
        pxx, pxy, pyy = info_point[m, 0], info_point[m, 1], info_point[m, 2]
        ax, ay = -rotated_points[m, 1], rotated_points[m, 0]
        bx, by = -rotated_normals[m, 1], rotated_normals[m, 0]
        oax, oay = pxx * ax + pxy * ay, pxy * ax + pyy * ay
        oex = pxx * point_error[m, 0] + pxy * point_error[m, 1]
        oey = pxy * point_error[m, 0] + pyy * point_error[m, 1]
        s[0] += w * pxx
        s[1] += w * pxy
        s[2] += w * pyy
        s[3] += w * oax
        s[4] += w * oay
        s[5] += w * (ax * oax + ay * oay + info_normal[m] * (bx * bx + by * by))
        s[6] += w * oex
        s[7] += w * oey
        s[8] += w * (ax * oex + ay * oey
                     + info_normal[m] * (bx * normal_error[m, 0] + by * normal_error[m, 1]))
    hessian = np.array([[s[0], s[1], s[3]], [s[1], s[2], s[4]], [s[3], s[4], s[5]]])
    return hessian, s[6:9].copy()


def is_degenerate(information: np.ndarray, length_scale: float,
                  min_information: float) -> bool:
    """Tell whether some direction of the information is too weak to trust.

    The pipeline's acceptance test (:func:`laser_odom.core.uncertainty.degeneracy.
    degenerate_directions`), so that the matcher's flag and the pipeline agree:
    rotation is measured as the arc at the scan's RMS range ``length_scale`` and any
    eigenvalue below ``min_information`` [1/m^2] (a featureless corridor's axis) is weak.
    """
    return bool(np.any(degenerate_directions(information, length_scale, min_information)[2]))


@numba.njit(cache=True, nogil=True)
def linearise(sorted_points: np.ndarray, bearings: np.ndarray, directions: np.ndarray,
              order: np.ndarray, ref_points: np.ndarray, ref_normals: np.ndarray,
              ref_log_curvature: np.ndarray, ref_usable: np.ndarray,
              ref_info_point: np.ndarray, ref_info_normal: np.ndarray, points: np.ndarray,
              normals: np.ndarray, log_curvature: np.ndarray, estimate: np.ndarray,
              max_distance: float, min_normal_cosine: float, max_curvature_ratio: float,
              kernel: int, kernel_scale: float) -> tuple:
    """Pair, filter and linearise NICP at ``estimate`` (compiled).

    The current ``points``/``normals`` (those with a usable normal) are moved by the
    estimate and paired (:func:`associate`); each pair's error ``e`` (eq. 2) is
    weighted by the reference information and the robust kernel (IRLS on the
    Mahalanobis error ``sqrt(e^T Omega e)``). Returns the number of pairs, ``H`` and
    ``g`` (:func:`normal_equations`), the RMS point-to-surface distance, the
    a-posteriori variance factor (weighted ``e^T Omega e`` per degree of freedom) and
    the terms behind the reported information (rotated points and normals, errors,
    reference indices, weights of the pairs).
    """
    turn = np.array([0.0, 0.0, estimate[2]])
    rotated, rotated_normals = move_points(turn, points), move_points(turn, normals)
    moved = move_points(estimate, points)
    count = points.shape[0]
    pick, ref_index = _associate(sorted_points, bearings, directions, order, ref_normals,
                                 ref_log_curvature, ref_usable, moved, rotated_normals,
                                 log_curvature, np.ones(count, dtype=np.bool_),
                                 max_distance, min_normal_cosine, max_curvature_ratio)
    pairs = pick.shape[0]
    point_error = np.empty((pairs, 2))
    normal_error = np.empty((pairs, 2))
    info_point = np.empty((pairs, 3))
    info_normal = np.empty(pairs)
    squared_distance = 0.0
    for m in range(pairs):
        i, j = pick[m], ref_index[m]
        point_error[m, 0] = moved[i, 0] - ref_points[j, 0]
        point_error[m, 1] = moved[i, 1] - ref_points[j, 1]
        normal_error[m, 0] = rotated_normals[i, 0] - ref_normals[j, 0]
        normal_error[m, 1] = rotated_normals[i, 1] - ref_normals[j, 1]
        info_point[m, 0], info_point[m, 1] = ref_info_point[j, 0], ref_info_point[j, 1]
        info_point[m, 2], info_normal[m] = ref_info_point[j, 2], ref_info_normal[j]
        along = point_error[m, 0] * ref_normals[j, 0] + point_error[m, 1] * ref_normals[j, 1]
        squared_distance += along * along
    chi2 = chi_squared(point_error, normal_error, info_point, info_normal)
    weights = kernel_weights(np.sqrt(chi2), kernel, kernel_scale)
    picked_points, picked_normals = rotated[pick], rotated_normals[pick]
    hessian, gradient = normal_equations(picked_points, picked_normals, point_error,
                                         normal_error, info_point, info_normal, weights)
    residual = math.sqrt(squared_distance / pairs) if pairs else 0.0
    variance_factor = (weights @ chi2) / max(weights.sum() - 3.0, 1.0)
    return (pairs, hessian, gradient, residual, variance_factor, picked_points,
            picked_normals, point_error, normal_error, ref_index, weights)
