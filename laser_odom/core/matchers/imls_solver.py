"""Point-to-plane Gauss-Newton pieces of IMLS-ICP and the fusion of its two directions.

The step (IMLS-SLAM eq. 2, Deschaud 2018) minimises ``sum_j w_j (n_j . (R x_j + t -
y_j))^2`` over the pose ``[x, y, theta]``, with ``y_j`` the projection of ``x_j`` onto
the reference's implicit surface and ``n_j`` its normal, both held fixed during a step.
"""

from __future__ import annotations

import numpy as np

from laser_odom.core import se2
from laser_odom.core.matchers.information import (
    covariance_from_information, point_to_line_jacobians)

EIGEN_FLOOR = 1e-9
"""Relative eigenvalue below which a Gauss-Newton direction is left unchanged."""

ROTATION_LEVER = 5.0
"""Metres per radian when comparing steps (a typical range of the scan points)."""


def point_to_plane_system(pose: se2.Pose, points: np.ndarray, normals: np.ndarray,
                          targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return residuals ``n . (R p + t - y)`` and their Jacobians (IMLS-SLAM eq. 2).

    The Jacobians are with respect to ``[x, y, theta]`` of ``pose`` itself (R = R(theta),
    t = (x, y)), so the Gauss-Newton increment is added to the pose directly.
    """
    rotated = se2.transform_points(np.array([0.0, 0.0, pose[2]]), points)
    residuals = np.einsum('nd,nd->n', rotated + pose[:2] - targets, normals)
    return residuals, point_to_line_jacobians(rotated, normals)


def gauss_newton_step(jacobians: np.ndarray, residuals: np.ndarray,
                      weights: np.ndarray) -> np.ndarray:
    """Return ``-H^+ J^T W r`` with ``H = J^T W J``; unconstrained directions stay put.

    The pseudo-inverse drops eigen-directions weaker than ``EIGEN_FLOOR`` times the
    strongest, so a direction the points do not constrain at all (points on one wall
    only) keeps its value instead of taking a step from round-off. Weak but real
    constraints are kept; the pipeline judges degeneracy from the information.
    """
    weighted = jacobians * weights[:, None]
    hessian = weighted.T @ jacobians
    gradient = weighted.T @ residuals
    values, vectors = np.linalg.eigh(hessian)
    strongest = max(float(values[-1]), 1e-300)
    inverse = np.where(values > EIGEN_FLOOR * strongest, 1.0 / np.maximum(values, 1e-300), 0.0)
    return -(vectors * inverse) @ (vectors.T @ gradient)


def step_cosine(step: np.ndarray, previous: np.ndarray) -> float:
    """Return the cosine between two steps, rotation as the arc at ``ROTATION_LEVER``."""
    scale = np.array([1.0, 1.0, ROTATION_LEVER])
    a, b = step * scale, previous * scale
    norm = float(np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.dot(a, b)) / norm if norm > 0.0 else 0.0


def advance(estimate: se2.Pose, step: np.ndarray) -> se2.Pose:
    """Return ``estimate + step`` with the angle wrapped."""
    moved = estimate + step
    moved[2] = se2.wrap_angle(moved[2])
    return moved


def inverted_information(backward_pose: se2.Pose, information: np.ndarray) -> np.ndarray:
    """Carry the information of a pose ``U`` to that of ``U^-1``: ``J^-T H J^-1``.

    ``J`` is the Jacobian of the inverse (:func:`se2.inverse_jacobian`); a match of
    the reference against the current scan estimates ``U = T^-1``, and this gives
    its information about ``T``.
    """
    jacobian_inverse = np.linalg.inv(se2.inverse_jacobian(backward_pose))
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
