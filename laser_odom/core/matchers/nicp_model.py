"""The NICP error model for 2D scans: extended points, pair rules, normal equations.

Serafin & Grisetti, "NICP: Dense Normal Based Point Cloud Registration", IROS 2015.
Every point becomes an *extended point* ``(p, n)`` (position and surface normal); the
transform acts as ``T (p, n) = (R p + t, R n)`` (Sec. III). A pair (current ``i``,
reference ``j``) has the 4-vector error

    e_ij = [R p_i + t - q_j ; R n_i - m_j]                                  (eq. 2)

weighted by the information ``Omega_j = diag(Omega_p_j, omega_n_j I2)`` of the
reference point (Sec. IV-B, built per scan in :mod:`.nicp_surface`): ``Omega_p`` is the
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

import numpy as np
from scipy.spatial import cKDTree

from laser_odom.core.degeneracy import degenerate_directions
from laser_odom.core.matchers.nicp_surface import NicpSurface


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

    The nearest reference point is searched among the measured points (``tree``);
    the errors then use the reference surface's (possibly smoothed) points.

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

    The pipeline's acceptance test (:func:`laser_odom.core.degeneracy.
    degenerate_directions`), so that the matcher's flag and the pipeline agree:
    rotation is measured as the arc at the scan's RMS range ``length_scale`` and any
    eigenvalue below ``min_information`` [1/m^2] (a featureless corridor's axis) is weak.
    """
    return bool(np.any(degenerate_directions(information, length_scale, min_information)[2]))
