"""Point-to-point ICP iterations with the closed-form SVD step, compiled.

Besl & McKay, "A method for registration of 3-D shapes", PAMI 1992: pair every point
with its nearest reference point (gated, trimmed), align the pairs in closed form
(Arun, Huang & Blostein, PAMI 1987: centre both sets, take the SVD of their
cross-covariance ``H = U S V^T``, ``R = V diag(1, det(V U^T)) U^T`` - the diagonal
fixes the reflection case - and ``t = mu_q - R mu_p``; in 2D that rotation has a
closed form, see :func:`align_pairs`), repeat. Point-to-point ICP
converges linearly, creeping along walls; two aligned, shrinking steps are
extrapolated to the end of their geometric tail (Besl & McKay, Sec. IV-C).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from laser_odom.core.matchers.robust import adaptive_keep_fraction, trimmed_mask
from laser_odom.core.scan.nearest import nearest_by_bearing
from laser_odom.core.se2 import is_small_step, move_points, relative_pose, wrap_angle

ACCELERATION_COSINE = math.cos(math.radians(10.0))
"""Successive steps closer than 10 deg in direction count as one consistent creep."""


@numba.njit(cache=True, nogil=True)
def align_pairs(source: np.ndarray, target: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Return the rigid pose minimising ``sum w_i |R s_i + t - q_i|^2`` (Arun et al.).

    Arun's solution takes the SVD of the weighted cross-covariance of the centred sets,
    ``H = sum w_i s_i q_i^T = U S V^T``, and ``R = V diag(1, det(V U^T)) U^T``: the
    rotation that maximises ``tr(R H)`` (Umeyama 1991). In the plane ``tr(R H) =
    cos(theta) (H_00 + H_11) + sin(theta) (H_01 - H_10)``, so that rotation is
    ``theta = atan2(H_01 - H_10, H_00 + H_11)`` - the SVD's answer, reflection case
    included, without factorising a 2x2 matrix every iteration.
    """
    w_sum = weights.sum()
    mu_s = weights @ source / w_sum
    mu_t = weights @ target / w_sum
    trace_part = 0.0  # H_00 + H_11
    skew_part = 0.0  # H_01 - H_10
    for i in range(source.shape[0]):
        sx, sy = source[i, 0] - mu_s[0], source[i, 1] - mu_s[1]
        tx, ty = target[i, 0] - mu_t[0], target[i, 1] - mu_t[1]
        trace_part += weights[i] * (sx * tx + sy * ty)
        skew_part += weights[i] * (sx * ty - sy * tx)
    theta = math.atan2(skew_part, trace_part)
    cos, sin = math.cos(theta), math.sin(theta)
    return np.array([mu_t[0] - (cos * mu_s[0] - sin * mu_s[1]),
                     mu_t[1] - (sin * mu_s[0] + cos * mu_s[1]), theta])


@numba.njit(cache=True, nogil=True)
def accelerated_extra(previous: np.ndarray, step: np.ndarray,
                      max_factor: float = 10.0) -> np.ndarray:
    """Extra move along a consistent ICP step direction (Besl & McKay 1992, Sec. IV-C).

    When two successive steps (in metric units) point the same way within 10 deg and
    shrink by a ratio r < 1, the remaining creep is the geometric tail
    ``step * r / (1 - r)``; jumping there saves tens of iterations. The next iteration
    re-pairs, so an overshoot is corrected.
    """
    norm_prev, norm_step = np.linalg.norm(previous), np.linalg.norm(step)
    if norm_prev == 0.0 or norm_step == 0.0:
        return np.zeros(3)
    aligned = (previous @ step) / (norm_prev * norm_step)
    ratio = norm_step / norm_prev
    if aligned < ACCELERATION_COSINE or ratio >= 1.0:
        return np.zeros(3)
    return step * min(ratio / (1.0 - ratio), max_factor)


@numba.njit(cache=True, nogil=True)
def iterate(sorted_points: np.ndarray, bearings: np.ndarray, directions: np.ndarray,
            order: np.ndarray, target: np.ndarray, points: np.ndarray, start: np.ndarray,
            max_iterations: int, min_correspondences: int, max_distance: float,
            min_keep_fraction: float, max_keep_fraction: float,
            convergence_translation: float, convergence_rotation: float,
            length_scale: float) -> tuple:
    """Run up to ``max_iterations`` ICP iterations against ``target`` (its index unpacked).

    Returns whether pairs lasted, the estimate, the iterations used and whether the
    step fell below the convergence thresholds. Steps are compared in metric units
    (rotation times the scan's RMS range ``length_scale``) for the extrapolation.
    """
    scale = np.array([1.0, 1.0, length_scale])
    estimate = start.copy()
    previous_step = np.zeros(3)
    has_previous = False
    hints = np.full(points.shape[0], -1, dtype=np.int64)
    for iteration in range(1, max_iterations + 1):
        distance, nearest = nearest_by_bearing(sorted_points, bearings, directions, order,
                                               move_points(estimate, points), max_distance,
                                               hints)
        found = np.flatnonzero(nearest < order.shape[0])
        if found.shape[0] < min_correspondences:
            return False, estimate, iteration, False
        gated = distance[found]
        keep = adaptive_keep_fraction(gated, min_keep_fraction, max_keep_fraction, 3.0)
        kept = found[trimmed_mask(gated, keep)]
        updated = align_pairs(points[kept], target[nearest[kept]], np.ones(kept.shape[0]))
        step = updated - estimate
        step[2] = wrap_angle(step[2])
        if is_small_step(relative_pose(estimate, updated), convergence_translation,
                         convergence_rotation):
            return True, updated, iteration, True
        estimate = updated
        if has_previous:
            estimate = estimate + accelerated_extra(previous_step * scale,
                                                    step * scale) / scale
        previous_step = step
        has_previous = True
    return True, estimate, max_iterations, False
