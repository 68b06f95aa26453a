"""Point-to-point ICP iterations with the closed-form SVD step, compiled.

Besl & McKay, "A method for registration of 3-D shapes", PAMI 1992: pair every point
with its nearest reference point (gated, trimmed), align the pairs in closed form
(Arun, Huang & Blostein, PAMI 1987: centre both sets, take the SVD of their
cross-covariance ``H = U S V^T``, ``R = V diag(1, det(V U^T)) U^T`` - the diagonal
fixes the reflection case - and ``t = mu_q - R mu_p``), repeat. Point-to-point ICP
converges linearly, creeping along walls; two aligned, shrinking steps are
extrapolated to the end of their geometric tail (Besl & McKay, Sec. IV-C).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from laser_odom.core.matchers.robust import adaptive_keep_fraction, trimmed_mask
from laser_odom.core.nearest import nearest_by_bearing
from laser_odom.core.se2 import move_points, relative_pose, wrap_angle

ACCELERATION_COSINE = math.cos(math.radians(10.0))
"""Successive steps closer than 10 deg in direction count as one consistent creep."""


@numba.njit(cache=True, nogil=True)
def align_svd(source: np.ndarray, target: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Return the rigid pose minimising ``sum w_i |R s_i + t - q_i|^2`` (Arun et al.)."""
    w_sum = weights.sum()
    mu_s = weights @ source / w_sum
    mu_t = weights @ target / w_sum
    cross = np.zeros((2, 2))
    for i in range(source.shape[0]):
        for a in range(2):
            for b in range(2):
                cross[a, b] += (source[i, a] - mu_s[a]) * (target[i, b] - mu_t[b]) * weights[i]
    u, _, vt = np.linalg.svd(cross)
    reflection = 1.0 if np.linalg.det(vt.T @ u.T) >= 0.0 else -1.0
    rot = vt.T @ np.diag(np.array([1.0, reflection])) @ u.T
    trans = mu_t - rot @ mu_s
    return np.array([trans[0], trans[1], math.atan2(rot[1, 0], rot[0, 0])])


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
        updated = align_svd(points[kept], target[nearest[kept]], np.ones(kept.shape[0]))
        step = updated - estimate
        step[2] = wrap_angle(step[2])
        change = relative_pose(estimate, updated)
        if (math.hypot(change[0], change[1]) < convergence_translation
                and abs(change[2]) < convergence_rotation):
            return True, updated, iteration, True
        estimate = updated
        if has_previous:
            estimate = estimate + accelerated_extra(previous_step * scale,
                                                    step * scale) / scale
        previous_step = step
        has_previous = True
    return True, estimate, max_iterations, False
