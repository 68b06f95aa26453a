"""Information and covariance of a match from its linearised residuals.

For residuals r_i with Jacobians J_i (with respect to ``[x, y, theta]``) and
weights w_i, the Gauss-Newton information is ``H = sum w_i J_i^T J_i / sigma^2``
with ``sigma^2`` the weighted residual variance (the inverse-Hessian covariance
estimate; Bengtsson & Baerveldt 2003, Censi 2007 for its ICP use).
"""

from __future__ import annotations

import numba
import numpy as np

MIN_RESIDUAL_SIGMA = 0.005
"""Floor on the residual standard deviation [m]: a noise-free fit is not infinitely certain."""


@numba.njit(cache=True, nogil=True)
def point_to_line_jacobians(rotated_points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Jacobians (N, 3) of ``n . (R p + t - q)`` with respect to ``[x, y, theta]``.

    ``rotated_points`` are ``R p`` (already rotated by the current estimate);
    d(R p)/d theta = [-(Rp)_y, (Rp)_x].
    """
    jacobians = np.empty((rotated_points.shape[0], 3))
    for i in range(rotated_points.shape[0]):
        nx, ny = normals[i, 0], normals[i, 1]
        jacobians[i, 0], jacobians[i, 1] = nx, ny
        jacobians[i, 2] = ny * rotated_points[i, 0] - nx * rotated_points[i, 1]
    return jacobians


@numba.njit(cache=True, nogil=True)
def point_to_line_information(rotated_points: np.ndarray, normals: np.ndarray,
                              residuals: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Return ``sum_i w_i J_i^T J_i / sigma^2`` of point-to-line residuals, in one pass.

    ``J_i`` as in :func:`point_to_line_jacobians`; ``sigma^2 = sum_i w_i r_i^2 / (sum_i
    w_i - 3)``, the weighted residual variance with the three pose parameters removed,
    floored at :data:`MIN_RESIDUAL_SIGMA` squared. Every matcher whose information is
    point to line (icp, plicp, imls) takes it from here.
    """
    return _information(rotated_points, normals, residuals, weights,
                        np.zeros(residuals.shape[0]))


@numba.njit(cache=True, nogil=True)
def debiased_point_to_line_information(rotated_points: np.ndarray, normals: np.ndarray,
                                       residuals: np.ndarray, weights: np.ndarray,
                                       normal_var: np.ndarray) -> np.ndarray:
    """Return :func:`point_to_line_information` debiased for the noise of the normals.

    ``J_i = A_i n_i`` is linear in the normal, ``A_i = [[1, 0], [0, 1], [-p_y, p_x]]``.
    A normal estimated with direction variance ``s^2``
    (:func:`.scan.normals.normal_variance`) has ``E[n n^T] = n0 n0^T + s^2 (t0 t0^T -
    n0 n0^T)``, ``t`` the tangent: summed over a corridor's walls, ``s^2 t t^T``
    claims that the axis is observed. Each term is therefore
    ``A ((1 + s^2) n n^T - s^2 t t^T) A^T``, an unbiased estimate of the information
    the surface holds (the errors-in-variables correction ``nicp`` makes,
    :func:`.nicp.surface.point_information`). Terms may be indefinite; the sum is
    projected onto the positive semi-definite cone (a direction that came out
    negative holds no information).
    """
    information = _information(rotated_points, normals, residuals, weights, normal_var)
    values, vectors = np.linalg.eigh(0.5 * (information + information.T))
    return (vectors * np.maximum(values, 0.0)) @ vectors.T


@numba.njit(cache=True, nogil=True)
def _information(rotated_points: np.ndarray, normals: np.ndarray, residuals: np.ndarray,
                 weights: np.ndarray, normal_var: np.ndarray) -> np.ndarray:
    """Return the point-to-line information, each normal's noise ``normal_var`` removed."""
    information = np.zeros((3, 3))
    total = squares = 0.0
    for i in range(residuals.shape[0]):
        nx, ny, w, s2 = normals[i, 0], normals[i, 1], weights[i], normal_var[i]
        px, py = rotated_points[i, 0], rotated_points[i, 1]
        jacobian = (nx, ny, ny * px - nx * py)
        tangent = (-ny, nx, nx * px + ny * py)
        for a in range(3):
            for b in range(3):
                information[a, b] += w * ((1.0 + s2) * jacobian[a] * jacobian[b]
                                          - s2 * tangent[a] * tangent[b])
        total += w
        squares += w * residuals[i] * residuals[i]
    variance = max(squares / max(total - 3.0, 1.0), MIN_RESIDUAL_SIGMA * MIN_RESIDUAL_SIGMA)
    return information / variance


def covariance_from_information(information: np.ndarray,
                                max_variance: float = 1e3) -> np.ndarray:
    """Invert an information matrix; unobservable directions get ``max_variance``.

    The eigen-decomposition keeps the result symmetric positive definite even when
    the information is singular (a corridor leaves one direction unconstrained).
    """
    return _regularised_inverse(np.ascontiguousarray(information, dtype=float),
                                float(max_variance))


@numba.njit(cache=True, nogil=True)
def _regularised_inverse(information: np.ndarray, max_variance: float) -> np.ndarray:
    """Compiled :func:`covariance_from_information` (called once or more per match)."""
    values, vectors = np.linalg.eigh(0.5 * (information + information.T))
    variances = np.empty_like(values)
    for i in range(values.shape[0]):
        variances[i] = 1.0 / max(values[i], 1e-300) if values[i] > 1.0 / max_variance \
            else max_variance
    return (vectors * variances) @ vectors.T
