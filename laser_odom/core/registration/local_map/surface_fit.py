"""The last refinement of a map match: the scan's points on the map's own surfaces.

A match against the map sees the map as a virtual scan from the previous pose
(:mod:`laser_odom.core.registration.local_map.view`): one point per bearing bin, where
the bin's ray meets the pooled surface of the cells it crosses. That is what lets every
matcher take the map as it takes a scan, but it is a resampling: a wall seen at a
grazing angle, a corner, a far wall whose bins are wider than its cells, all lose
detail. Here the matched pose is refined once more against the cells themselves, with
no view in between: each point of the scan is paired with the nearest cell mean among
the 3x3 cells around it, and its residual is the distance to that cell's block
surface, the total-least-squares line of the block's pooled moments
(:mod:`laser_odom.core.registration.local_map.cells`). This is the scan-to-model
metric of IMLS-SLAM (Deschaud 2018, Sec. III: points against the model's surfaces,
not against another scan) and NICP's point-to-plane term, and, like hector_mapping's
matcher (Kohlbrecher et al. 2011, Sec. IV-A), the whole map's memory answers, not only
what the previous pose could see.

The pose is found by Gauss-Newton on the Huber-weighted point-to-line residuals
``r_i = n_i . (R p_i + t - m_i)`` (Jacobian ``[n_x, n_y, n . (R' p_i)]``, with ``R'``
the derivative of the rotation), from the matcher's pose, which lies well inside the
basin: the refinement corrects centimetres and tenths of a degree, not the step.
Curved or cluttered blocks (curvature above :data:`MAX_CURVATURE`) have no line and
pair nothing.

Along a corridor's axis the cells hold little: a door frame, the far end, smeared by
the scans that joined while the map's own pose erred there. Gauss-Newton still moves
the pose along such a direction by whatever those few pairs say, and on Intel that
shortened ``nicp``'s path by 0.6 % (50 m drift 0.44 -> 1.06 %, copy 2). So the
correction can be kept only where the cells measure it (solution remapping: Zhang,
Kaess and Singh, "On degeneracy of optimization-based state estimation problems", ICRA
2016, Sec. IV): in the eigen-directions of the Gauss-Newton Hessian at the refined pose
(rotation scaled to an arc at the points' RMS range) whose eigenvalue is below a share
of the pairs (the matcher's ``map_surface_weak_share``), the matcher's pose stands.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from laser_odom.core.registration.local_map.cells import (
    ALIVE, block_cells, BLOCK_WEIGHT, BLOCK_X, BLOCK_XX, BLOCK_XY, BLOCK_Y, BLOCK_YY, cell_key,
    line_normal, MEAN_X, MEAN_Y)
from laser_odom.core.uncertainty.degeneracy import degenerate_directions, metric_scale

MAX_CURVATURE = 0.1
"""A block whose smaller scatter eigenvalue is more than this share of the sum
(Pauly et al. 2002) is no line to measure a distance to."""

HUBER_SIGMA = 0.05
"""Residuals beyond this [m] count linearly (Huber): a point on something the map
does not hold pulls with a bounded force."""

ITERATIONS = 10
"""Gauss-Newton iterations at most (it converges in three to five from a match)."""

CONVERGED = (1e-5, 1e-6)
"""An iteration that moves the pose less than this [m, rad] ends the refinement."""

MIN_PAIRS = 20
"""With fewer paired points the refinement does not run: the matcher's pose stands."""


def fit_to_surfaces(points: np.ndarray, pose: np.ndarray, floats: np.ndarray,
                    ints: np.ndarray, slot_keys: np.ndarray, slot_cells: np.ndarray,
                    inverse_resolution: float, weak_share: float = 0.0
                    ) -> tuple[np.ndarray, int]:
    """Refine ``pose`` (base in the map frame) of base-frame ``points`` on the cells.

    Returns the refined pose and how many points were paired in its last iteration;
    the given pose, unchanged, when fewer than :data:`MIN_PAIRS` could be. With
    ``weak_share`` > 0 the correction is kept only in the directions the cells measure
    (:func:`measured_correction`).
    """
    points = np.ascontiguousarray(points, dtype=float)
    start = np.asarray(pose, dtype=float)
    refined, pairs = _fit(points, start, floats, ints, slot_keys, slot_cells,
                          float(inverse_resolution), ITERATIONS, HUBER_SIGMA, MAX_CURVATURE,
                          MIN_PAIRS, CONVERGED[0], CONVERGED[1])
    if pairs < MIN_PAIRS or weak_share <= 0.0:
        return refined, pairs
    hessian, _, paired = normal_equations(points, refined, floats, ints, slot_keys,
                                          slot_cells, float(inverse_resolution),
                                          HUBER_SIGMA, MAX_CURVATURE)
    if paired < MIN_PAIRS:
        return refined, pairs
    length = max(float(np.sqrt(np.mean(np.sum(points ** 2, axis=1)))), 0.1)
    return measured_correction(start, refined, hessian, weak_share * paired, length), pairs


def measured_correction(start: np.ndarray, refined: np.ndarray, hessian: np.ndarray,
                        weakest: float, length: float) -> np.ndarray:
    """Return ``start`` corrected towards ``refined`` only where ``hessian`` measures it.

    The Gauss-Newton Hessian (x, y, theta) is judged in metric units, a rotation as its
    arc at ``length`` [m] (a point on a wall square to a direction adds one:
    :func:`.uncertainty.degeneracy.degenerate_directions`); the correction's component
    along each eigenvector whose eigenvalue is below ``weakest`` is removed (Zhang et
    al. 2016, solution remapping).
    """
    scale = metric_scale(length)
    _, vectors, weak = degenerate_directions(hessian, length, weakest)
    correction = (np.asarray(refined, dtype=float) - start) / scale
    for k in np.flatnonzero(weak):
        correction -= vectors[:, k] * (vectors[:, k] @ correction)
    return start + correction * scale


@numba.njit(cache=True, nogil=True)
def _fit(points: np.ndarray, pose: np.ndarray, floats: np.ndarray, ints: np.ndarray,
         slot_keys: np.ndarray, slot_cells: np.ndarray, inverse_resolution: float,
         iterations: int, sigma: float, max_curvature: float, min_pairs: int,
         converged_linear: float, converged_angular: float) -> tuple[np.ndarray, int]:
    """Gauss-Newton on the Huber-weighted point-to-line residuals (the module's equation)."""
    x, y, theta = pose[0], pose[1], pose[2]
    pairs = 0
    for _ in range(iterations):
        hessian, gradient, pairs = normal_equations(
            points, np.array([x, y, theta]), floats, ints, slot_keys, slot_cells,
            inverse_resolution, sigma, max_curvature)
        if pairs < min_pairs:
            return pose.copy(), pairs
        for a in range(3):
            hessian[a, a] += 1e-9
        delta = np.linalg.solve(hessian, -gradient)
        x, y, theta = x + delta[0], y + delta[1], theta + delta[2]
        if (abs(delta[0]) < converged_linear and abs(delta[1]) < converged_linear
                and abs(delta[2]) < converged_angular):
            break
    return np.array([x, y, theta]), pairs


@numba.njit(cache=True, nogil=True)
def normal_equations(points: np.ndarray, pose: np.ndarray, floats: np.ndarray,
                     ints: np.ndarray, slot_keys: np.ndarray, slot_cells: np.ndarray,
                     inverse_resolution: float, sigma: float, max_curvature: float
                     ) -> tuple[np.ndarray, np.ndarray, int]:
    """Return the Gauss-Newton Hessian and gradient of the residuals at ``pose``, and the pairs.

    Each point is paired with the nearest cell of the 3x3 around it that has a line;
    its Huber weight is one within ``sigma`` [m] and falls beyond.
    """
    cos_t, sin_t = math.cos(pose[2]), math.sin(pose[2])
    hessian = np.zeros((3, 3))
    gradient = np.zeros(3)
    pairs = 0
    block = np.empty(9, dtype=np.int64)
    for k in range(points.shape[0]):
        # The point in the map frame, and its lever arm about the base (R p).
        ax = cos_t * points[k, 0] - sin_t * points[k, 1]
        ay = sin_t * points[k, 0] + cos_t * points[k, 1]
        wx, wy = ax + pose[0], ay + pose[1]
        cell = _nearest_cell(wx, wy, floats, ints, slot_keys, slot_cells,
                             inverse_resolution, block)
        if cell < 0:
            continue
        nx, ny = line_normal(floats[cell, BLOCK_XX], floats[cell, BLOCK_XY],
                             floats[cell, BLOCK_YY], max_curvature)
        if nx == 0.0 and ny == 0.0:
            continue
        residual = nx * (wx - floats[cell, BLOCK_X]) + ny * (wy - floats[cell, BLOCK_Y])
        magnitude = abs(residual)
        weight = 1.0 if magnitude <= sigma else sigma / magnitude
        jacobian = (nx, ny, nx * -ay + ny * ax)
        for a in range(3):
            gradient[a] += weight * jacobian[a] * residual
            for b in range(3):
                hessian[a, b] += weight * jacobian[a] * jacobian[b]
        pairs += 1
    return hessian, gradient, pairs


@numba.njit(cache=True, nogil=True, inline='always')
def _nearest_cell(x: float, y: float, floats: np.ndarray, ints: np.ndarray,
                  slot_keys: np.ndarray, slot_cells: np.ndarray, inverse_resolution: float,
                  block: np.ndarray) -> int:
    """Return the cell of the 3x3 around ``(x, y)`` whose mean is nearest, -1 if none.

    ``block`` is scratch space for the block's cells (:func:`.cells.block_cells`).
    """
    best, best_distance = -1, math.inf
    for k in range(block_cells(cell_key(x, y, inverse_resolution), slot_keys, slot_cells,
                               block)):
        cell = block[k]
        if ints[cell, ALIVE] == 0 or floats[cell, BLOCK_WEIGHT] <= 0.0:
            continue
        dx, dy = x - floats[cell, MEAN_X], y - floats[cell, MEAN_Y]
        distance = dx * dx + dy * dy
        if distance < best_distance:
            best, best_distance = cell, distance
    return best
