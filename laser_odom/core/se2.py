"""SE(2) algebra for planar poses stored as ``numpy`` arrays ``[x, y, theta]``.

A pose ``a`` maps points from its own frame into its parent frame:
``p_parent = R(theta) p + t``. Composition follows that convention, so
``compose(world_T_a, a_T_b) == world_T_b``. Angles are radians (REP-103).
"""

from __future__ import annotations

import math

import numba
import numpy as np

Pose = np.ndarray
"""A planar pose ``[x, y, theta]`` (float64, shape (3,))."""


@numba.njit(cache=True, nogil=True)
def wrap_angle(angle: float | np.ndarray) -> float | np.ndarray:
    """Wrap an angle (or array of angles) into [-pi, pi) (compiled: kernels use it too)."""
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def pose(x: float = 0.0, y: float = 0.0, theta: float = 0.0) -> Pose:
    """Build a pose array."""
    return np.array([x, y, theta], dtype=float)


def rotation(theta: float) -> np.ndarray:
    """Return the 2x2 rotation matrix R(theta)."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def to_matrix(p: Pose) -> np.ndarray:
    """Return the 3x3 homogeneous matrix of a pose."""
    c, s = math.cos(p[2]), math.sin(p[2])
    return np.array([[c, -s, p[0]], [s, c, p[1]], [0.0, 0.0, 1.0]])


def from_matrix(m: np.ndarray) -> Pose:
    """Return the pose of a 3x3 homogeneous (or 2x3) rigid transform matrix."""
    return np.array([m[0, 2], m[1, 2], math.atan2(m[1, 0], m[0, 0])])


def compose(a: Pose, b: Pose) -> Pose:
    """Return ``a * b``: the pose b expressed in a's parent frame."""
    return compose_poses(np.asarray(a, dtype=float), np.asarray(b, dtype=float))


def inverse(a: Pose) -> Pose:
    """Return ``a^-1``."""
    return inverse_pose(np.asarray(a, dtype=float))


def relative(a: Pose, b: Pose) -> Pose:
    """Return ``a^-1 * b``: the pose of b seen from a (the motion from a to b)."""
    return relative_pose(np.asarray(a, dtype=float), np.asarray(b, dtype=float))


@numba.njit(cache=True, nogil=True)
def compose_poses(a: Pose, b: Pose) -> Pose:
    """Compiled :func:`compose` of two float pose arrays (for kernels and the wrapper)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([
        a[0] + c * b[0] - s * b[1],
        a[1] + s * b[0] + c * b[1],
        wrap_angle(a[2] + b[2]),
    ])


@numba.njit(cache=True, nogil=True)
def inverse_pose(a: Pose) -> Pose:
    """Compiled :func:`inverse` of a float pose array."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([
        -c * a[0] - s * a[1],
        s * a[0] - c * a[1],
        wrap_angle(-a[2]),
    ])


@numba.njit(cache=True, nogil=True)
def relative_pose(a: Pose, b: Pose) -> Pose:
    """Compiled :func:`relative` of two float pose arrays."""
    return compose_poses(inverse_pose(a), b)


def transform_points(p: Pose, points: np.ndarray) -> np.ndarray:
    """Apply a pose to an (N, 2) array of points: ``R p_i + t``."""
    return move_points(np.asarray(p, dtype=float),
                       np.asarray(points, dtype=float).reshape(-1, 2))


@numba.njit(cache=True, nogil=True)
def move_points(p: Pose, points: np.ndarray) -> np.ndarray:
    """Compiled :func:`transform_points` of float arrays (for kernels and the wrapper)."""
    c, s = math.cos(p[2]), math.sin(p[2])
    out = np.empty((points.shape[0], 2))
    for i in range(points.shape[0]):
        x, y = points[i, 0], points[i, 1]
        out[i, 0] = c * x - s * y + p[0]
        out[i, 1] = s * x + c * y + p[1]
    return out


@numba.njit(cache=True, nogil=True)
def is_small_step(step: Pose, translation: float, rotation: float) -> bool:
    """Tell whether a step moves less than ``translation`` and turns less than ``rotation``.

    The convergence test of every matcher's compiled iterations (and of their coarse
    stages, with one tolerance for both).
    """
    return math.hypot(step[0], step[1]) < translation and abs(step[2]) < rotation


def inverse_jacobian(a: Pose) -> np.ndarray:
    """Return the Jacobian of ``inverse(a)`` with respect to ``a`` (``[x, y, theta]``).

    ``inverse(a) = (-R^T t, -theta)``; the Jacobian maps a perturbation of a pose to
    that of its inverse, e.g. to carry the covariance of a match made the other way
    round (reference against current) into the frame of the forward one.
    """
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([
        [-c, -s, s * a[0] - c * a[1]],
        [s, -c, c * a[0] + s * a[1]],
        [0.0, 0.0, -1.0],
    ])


def compose_jacobians(a: Pose, b: Pose) -> tuple[np.ndarray, np.ndarray]:
    """Return the Jacobians of ``compose(a, b)`` with respect to a and to b.

    Used for first-order covariance propagation of the integrated pose:
    ``Sigma_ab = Ja Sigma_a Ja^T + Jb Sigma_b Jb^T`` (the classic planar
    compounding of Smith, Self and Cheeseman).
    """
    c, s = math.cos(a[2]), math.sin(a[2])
    ja = np.array([
        [1.0, 0.0, -s * b[0] - c * b[1]],
        [0.0, 1.0, c * b[0] - s * b[1]],
        [0.0, 0.0, 1.0],
    ])
    jb = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return ja, jb


def yaw_to_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """Return the quaternion ``(x, y, z, w)`` of a rotation by ``yaw`` about z."""
    half = 0.5 * yaw
    return 0.0, 0.0, math.sin(half), math.cos(half)


def quaternion_to_yaw(x: float, y: float, z: float, w: float) -> float:
    """Return the yaw (rotation about z, ZYX convention) of a quaternion."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def is_finite_pose(p: Pose) -> bool:
    """Tell whether every component of a pose is finite."""
    return bool(np.all(np.isfinite(p)))
