"""NICP's robust, damped Gauss-Newton iterations on SE(2), compiled.

Serafin & Grisetti, "NICP", IROS 2015, Sec. IV-C: every iteration pairs the points
again and linearises (:func:`.nicp.model.linearise`), then solves the damped normal
equations ``(H + mu diag H) dx = -g`` (a fixed relative damping ``mu``, not an
adaptive Levenberg-Marquardt lambda). A step that (nearly) undoes the previous one
means the pairing flips between two sets: halving the steps on every such reversal
settles between them, and ordinary corrections restore full steps. The iteration
stops on a small step, on a step that changes ``e^T Omega e`` by less than
``convergence_chi2`` (a direction the scene hardly constrains), or at the cap.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from laser_odom.core.matchers.nicp.model import linearise
from laser_odom.core.se2 import is_small_step, wrap_angle

FAILED_PAIRS = 1
"""Status of :func:`gauss_newton`: too few pairs at some iteration."""

FAILED_SINGULAR = 2
"""Status of :func:`gauss_newton`: a singular or non-finite system."""


@numba.njit(cache=True, nogil=True)
def damped_step(hessian: np.ndarray, gradient: np.ndarray, damping: float) -> np.ndarray:
    """Return ``-(H + mu diag H)^-1 g`` (Cramer's rule on the 3x3), NaN if singular."""
    a = hessian.copy()
    for d in range(3):
        a[d, d] += damping * hessian[d, d]
    det = (a[0, 0] * (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1])
           - a[0, 1] * (a[1, 0] * a[2, 2] - a[1, 2] * a[2, 0])
           + a[0, 2] * (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]))
    step = np.full(3, np.nan)
    if det == 0.0 or not math.isfinite(det):
        return step
    for column in range(3):
        replaced = a.copy()
        replaced[:, column] = gradient
        step[column] = -(replaced[0, 0] * (replaced[1, 1] * replaced[2, 2]
                                           - replaced[1, 2] * replaced[2, 1])
                         - replaced[0, 1] * (replaced[1, 0] * replaced[2, 2]
                                             - replaced[1, 2] * replaced[2, 0])
                         + replaced[0, 2] * (replaced[1, 0] * replaced[2, 1]
                                             - replaced[1, 1] * replaced[2, 0])) / det
    return step


@numba.njit(cache=True, nogil=True)
def undoes(step: np.ndarray, previous: np.ndarray) -> bool:
    """Tell whether ``step`` flips back along ``previous``.

    Over 120 degrees apart and at least half as long: the pairing flips between two
    sets, unlike an ordinary (small) Gauss-Newton correction of an overshoot.
    """
    length, previous_length = np.linalg.norm(step), np.linalg.norm(previous)
    return (step @ previous < -0.5 * length * previous_length
            and length > 0.5 * previous_length)


@numba.njit(cache=True, nogil=True)
def gauss_newton(sorted_points: np.ndarray, bearings: np.ndarray, directions: np.ndarray,
                 order: np.ndarray, ref_points: np.ndarray, ref_normals: np.ndarray,
                 ref_log_curvature: np.ndarray, ref_usable: np.ndarray,
                 ref_info_point: np.ndarray, ref_info_normal: np.ndarray,
                 points: np.ndarray, normals: np.ndarray, log_curvature: np.ndarray,
                 start: np.ndarray, max_iterations: int, min_correspondences: int,
                 max_distance: float, min_normal_cosine: float, max_curvature_ratio: float,
                 kernel: int, kernel_scale: float, damping: float,
                 convergence_translation: float, convergence_rotation: float,
                 convergence_chi2: float) -> tuple:
    """Iterate from ``start`` (compiled; the loop of ``NicpMatcher._optimise``).

    Returns the status (0, :data:`FAILED_PAIRS`, :data:`FAILED_SINGULAR`), the
    estimate, whether it converged, the iterations and the last linearisation
    (:func:`.nicp.model.linearise`'s tuple).
    """
    estimate = start.copy()
    previous = np.zeros(3)
    shrink = 1.0
    converged = False
    iterations = 0
    system = linearise(sorted_points, bearings, directions, order, ref_points, ref_normals,
                       ref_log_curvature, ref_usable, ref_info_point, ref_info_normal,
                       points, normals, log_curvature, estimate, max_distance,
                       min_normal_cosine, max_curvature_ratio, kernel, kernel_scale)
    for iterations in range(1, max_iterations + 1):
        if iterations > 1:
            system = linearise(sorted_points, bearings, directions, order, ref_points,
                               ref_normals, ref_log_curvature, ref_usable, ref_info_point,
                               ref_info_normal, points, normals, log_curvature, estimate,
                               max_distance, min_normal_cosine, max_curvature_ratio,
                               kernel, kernel_scale)
        if system[0] < min_correspondences:
            return FAILED_PAIRS, start, False, iterations, system
        hessian, gradient = system[1], system[2]
        step = damped_step(hessian, gradient, damping)
        if not np.all(np.isfinite(step)):
            return FAILED_SINGULAR, start, False, iterations, system
        if undoes(step, previous):
            shrink *= 0.5
        else:
            shrink = min(1.0, 2.0 * shrink)
        step = shrink * step
        previous = step
        estimate = estimate + step
        estimate[2] = wrap_angle(estimate[2])
        if (is_small_step(step, convergence_translation, convergence_rotation)
                or step @ hessian @ step < convergence_chi2):
            converged = True
            break
    return 0, estimate, converged, iterations, system
