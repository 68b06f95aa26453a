"""Point-to-plane Gauss-Newton pieces of IMLS-ICP and the fusion of its two directions.

The step (IMLS-SLAM eq. 2, Deschaud 2018) minimises ``sum_j w_j (n_j . (R x_j + t -
y_j))^2`` over the pose ``[x, y, theta]``, with ``y_j`` the projection of ``x_j`` onto
the reference's implicit surface and ``n_j`` its normal, both held fixed during a step.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from laser_odom.core import se2
from laser_odom.core.matchers.imls.surface import (
    implicit_surface_kernel, planarity, project_onto_surface)
from laser_odom.core.matchers.information import (
    covariance_from_information, debiased_point_to_line_information, point_to_line_jacobians)
from laser_odom.core.matchers.robust import inlier_mask, kernel_weights
from laser_odom.core.se2 import is_small_step, move_points, wrap_angle

EIGEN_FLOOR = 1e-9
"""Relative eigenvalue below which a Gauss-Newton direction is left unchanged."""

ROTATION_LEVER = 5.0
"""Metres per radian when comparing steps (a typical range of the scan points)."""


@numba.njit(cache=True, nogil=True)
def point_to_plane_system(pose: se2.Pose, points: np.ndarray, normals: np.ndarray,
                          targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return residuals ``n . (R p + t - y)`` and their Jacobians (IMLS-SLAM eq. 2).

    The Jacobians are with respect to ``[x, y, theta]`` of ``pose`` itself (R = R(theta),
    t = (x, y)), so the Gauss-Newton increment is added to the pose directly.
    """
    c, s = math.cos(pose[2]), math.sin(pose[2])
    rotated = np.empty_like(points)
    residuals = np.empty(points.shape[0])
    for i in range(points.shape[0]):
        rotated[i, 0] = c * points[i, 0] - s * points[i, 1]
        rotated[i, 1] = s * points[i, 0] + c * points[i, 1]
        residuals[i] = ((rotated[i, 0] + pose[0] - targets[i, 0]) * normals[i, 0]
                        + (rotated[i, 1] + pose[1] - targets[i, 1]) * normals[i, 1])
    return residuals, point_to_line_jacobians(rotated, normals)


@numba.njit(cache=True, nogil=True)
def gauss_newton_step(jacobians: np.ndarray, residuals: np.ndarray,
                      weights: np.ndarray) -> np.ndarray:
    """Return ``-H^+ J^T W r`` with ``H = J^T W J``; unconstrained directions stay put.

    The pseudo-inverse drops eigen-directions weaker than ``EIGEN_FLOOR`` times the
    strongest, so a direction the points do not constrain at all (points on one wall
    only) keeps its value instead of taking a step from round-off. Weak but real
    constraints are kept; the pipeline judges degeneracy from the information.
    """
    weighted = np.ascontiguousarray(jacobians * weights.reshape(-1, 1))
    hessian = weighted.T @ np.ascontiguousarray(jacobians)
    gradient = weighted.T @ residuals
    values, vectors = np.linalg.eigh(hessian)
    strongest = max(values[-1], 1e-300)
    inverse = np.zeros(3)
    for d in range(3):
        if values[d] > EIGEN_FLOOR * strongest:
            inverse[d] = 1.0 / max(values[d], 1e-300)
    return -(vectors * inverse) @ (vectors.T @ gradient)


@numba.njit(cache=True, nogil=True)
def step_cosine(step: np.ndarray, previous: np.ndarray) -> float:
    """Return the cosine between two steps, rotation as the arc at ``ROTATION_LEVER``."""
    scale = np.array([1.0, 1.0, ROTATION_LEVER])
    a, b = step * scale, previous * scale
    norm = np.linalg.norm(a) * np.linalg.norm(b)
    return (a @ b) / norm if norm > 0.0 else 0.0


@numba.njit(cache=True, nogil=True)
def advance(estimate: se2.Pose, step: np.ndarray) -> se2.Pose:
    """Return ``estimate + step`` with the angle wrapped."""
    moved = estimate + step
    moved[2] = wrap_angle(moved[2])
    return moved


def inverted_information(backward_pose: se2.Pose, information: np.ndarray) -> np.ndarray:
    """Carry the information of a pose ``U`` to that of ``U^-1``: ``J^-T H J^-1``.

    ``J`` is the Jacobian of the inverse (:func:`se2.inverse_jacobian`); a match of
    the reference against the current scan estimates ``U = T^-1``, and this gives
    its information about ``T``. Inversion undoes itself, so by the chain rule
    ``J(U)^-1`` is the Jacobian at ``U^-1``: no matrix inverse is needed.
    """
    jacobian_inverse = se2.inverse_jacobian(se2.inverse(backward_pose))
    carried = jacobian_inverse.T @ information @ jacobian_inverse
    return 0.5 * (carried + carried.T)


def fuse_directions(forward_pose: se2.Pose, forward_information: np.ndarray,
                    backward_pose: se2.Pose, backward_information: np.ndarray
                    ) -> tuple[se2.Pose, np.ndarray]:
    """Fuse the forward estimate of T with a backward estimate of ``U = T^-1``.

    Each direction's cost is quadratic about its minimum with its Gauss-Newton
    information as the Hessian, so the minimum of their sum is the information-
    weighted mean ``T_f + (H_f + H_b)^-1 H_b (T_b - T_f)`` (``H_b`` and ``T_b`` carried
    to T by :func:`inverted_information` and the inverse). Returns the fused pose and
    the difference ``T_b - T_f`` (angle wrapped).
    """
    carried_pose = se2.inverse(backward_pose)
    carried_information = inverted_information(backward_pose, backward_information)
    difference = carried_pose - forward_pose
    difference[2] = se2.wrap_angle(difference[2])
    total = covariance_from_information(forward_information + carried_information)
    return advance(forward_pose, total @ carried_information @ difference), difference


@numba.njit(cache=True, nogil=True)
def refine(sorted_points: np.ndarray, bearings: np.ndarray, directions: np.ndarray,
           order: np.ndarray, normals: np.ndarray, usable: np.ndarray, offset: np.ndarray,
           curvature: np.ndarray, chosen: np.ndarray, first_value: np.ndarray,
           first_normal: np.ndarray, first_defined: np.ndarray, first_mean: np.ndarray,
           first_nearest: np.ndarray, estimate: np.ndarray, far: bool, capture: float,
           h: float, radius: float, max_neighbours: int, min_neighbours: int,
           max_iterations: int, min_correspondences: int, nearest_normal: bool,
           kernel: int, kernel_scale: float, planarity_power: float,
           coarse_tolerance: float, coarse_share: float, aligned_cosine: float,
           max_gain: float, min_keep_fraction: float, outlier_sigmas: float,
           convergence_translation: float, convergence_rotation: float) -> tuple:
    """Iterate projection and Gauss-Newton steps (compiled ``ImlsMatcher._refine``).

    The model arrays are the reference's padded surface model and its index; the
    ``first_*`` arrays are the surface at the ``chosen`` points under ``estimate``
    within the capture radius, used by the first iteration when the guess is ``far``.
    Two stages: the approach (unit weights, extrapolated aligned steps, the capture
    radius when far) until a step moves less than ``coarse_tolerance``, then the
    refinement on an inlier set fixed once (adaptive trimming of the surface
    distances), with the robust kernel and steps halved when they reverse. Returns
    the estimate, whether it converged and the iterations.
    """
    approach_radius = capture if far else radius
    approach, converged, gated = True, False, False
    iterations = 0
    previous_step = np.zeros(3)
    gain = 1.0
    value, normal, defined, mean, nearest = (first_value, first_normal, first_defined,
                                             first_mean, first_nearest)
    k = max(1, min(max_neighbours, order.shape[0]))
    while iterations < max_iterations:
        iterations += 1
        if iterations > 1 or not far:
            value, normal, defined, _, mean, nearest = implicit_surface_kernel(
                sorted_points, bearings, directions, order, normals, usable, offset,
                move_points(estimate, chosen),
                h, approach_radius if approach else radius, k, max(min_neighbours, 1))
        ok = defined
        if not approach and not gated:
            # Entering the refinement: fix the inlier set once (close to the solution,
            # so that only true outliers stand out), so the iterations do not cycle.
            inlier = np.zeros(ok.shape[0], dtype=np.bool_)
            inlier[np.flatnonzero(ok)] = inlier_mask(value[ok], min_keep_fraction,
                                                     outlier_sigmas)
            chosen, value, normal = chosen[inlier], value[inlier], normal[inlier]
            mean, nearest, ok = mean[inlier], nearest[inlier], ok[inlier]
            gated, previous_step, gain = True, np.zeros(3), 1.0
        picked = np.flatnonzero(ok)
        if picked.shape[0] < min_correspondences:
            break
        along = normal[picked] if nearest_normal else mean[picked]
        points = chosen[picked]
        targets = project_onto_surface(move_points(estimate, points), value[picked], along)
        residuals, jacobians = point_to_plane_system(estimate, points, along, targets)
        weights = np.ones(residuals.shape[0]) if approach else kernel_weights(
            residuals, kernel, kernel_scale)
        if planarity_power > 0.0:
            weights = weights * planarity(curvature[nearest[picked]]) ** planarity_power
        step = gauss_newton_step(jacobians, residuals, weights)
        cosine = step_cosine(step, previous_step)
        if approach:
            # Far from the solution, pairings change a little every iteration and the
            # steps creep along one direction: extrapolate them (accelerated ICP,
            # Besl & McKay 1992, section IV-C).
            gain = min(2.0 * gain, max_gain) if cosine > aligned_cosine else 1.0
        elif cosine < 0.0:
            # The nearest-point normal jumps when the nearest point changes, so plain
            # steps can cycle between two poses; shrink them until they settle.
            gain *= 0.5
        previous_step = step
        estimate = advance(estimate, gain * step)
        if approach:
            approach = (not is_small_step(step, coarse_tolerance, coarse_tolerance)
                        and iterations < coarse_share * max_iterations)
        elif is_small_step(gain * step, convergence_translation, convergence_rotation):
            converged = True
            break
    return estimate, converged, iterations


@numba.njit(cache=True, nogil=True)
def surface_information(moved: np.ndarray, translation: np.ndarray, values: np.ndarray,
                        normals: np.ndarray, normal_var: np.ndarray, usable: np.ndarray,
                        min_keep_fraction: float, outlier_sigmas: float, kernel: int,
                        robust_scale: float) -> tuple[np.ndarray, float]:
    """Return the information and RMS surface distance of a final estimate.

    Over the ``usable`` points (surface value defined, normal usable) of the current
    scan ``moved`` by the estimate: the adaptive inliers of their surface distances
    ``values`` (:func:`.robust.inlier_mask`), weighted by the robust kernel, give the
    point-to-plane information, debiased for the variance ``normal_var`` of each
    normal (:func:`.information.debiased_point_to_line_information`, lever arms from
    the estimate's ``translation``), and the RMS of the inlier distances.
    """
    index = np.flatnonzero(usable)
    kept = index[inlier_mask(values[index], min_keep_fraction, outlier_sigmas)]
    residuals = values[kept]
    levers = moved[kept] - translation
    information = debiased_point_to_line_information(
        levers, normals[kept], residuals, kernel_weights(residuals, kernel, robust_scale),
        normal_var[kept])
    return information, math.sqrt(np.mean(residuals * residuals))
