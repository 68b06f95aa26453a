"""Exact closed-form step of PL-ICP: point-to-line least squares over SE(2).

Censi, "An ICP variant using a point-to-line metric", ICRA 2008, Sec. IV and appendix
(CSM's ``gpc_solve``): with ``x = (t_x, t_y, cos theta, sin theta)`` the sum of squared
point-to-line errors is a quadratic in ``x`` under the constraint ``x3^2 + x4^2 = 1``;
its Lagrange multiplier is a root of a fourth-degree polynomial, so the global minimum
of each iteration is found exactly, without a generic optimiser or linearisation.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from laser_odom.core import se2
from laser_odom.core.matchers.plicp.quartic import quartic_candidates
from laser_odom.core.matchers.plicp.segments import pair_and_trim
from laser_odom.core.se2 import compose_poses, is_small_step, relative_pose

TRANSLATION_RIDGE = 1e-12
"""Relative ridge on the translation block: an unconstrained direction (corridor axis)
gets a zero increment instead of a singular solve."""


def solve_point_to_line(points: np.ndarray, targets: np.ndarray, normals: np.ndarray,
                        weights: np.ndarray | None = None) -> se2.Pose:
    """Return the pose minimising ``sum w_i (n_i^T (R p_i + t - q_i))^2`` exactly.

    Censi 2008, appendix: ``n^T (R p + t) = a^T x`` with
    ``a = (n_x, n_y, n.p, n x p)`` and ``x = (t_x, t_y, cos theta, sin theta)``; see
    :func:`solve_design` for the constrained minimisation.
    """
    nx, ny = normals[:, 0], normals[:, 1]
    px, py = points[:, 0], points[:, 1]
    design = np.column_stack((nx, ny, nx * px + ny * py, ny * px - nx * py))
    offset = nx * targets[:, 0] + ny * targets[:, 1]
    return solve_design(design, offset, weights)


def solve_design(design: np.ndarray, offset: np.ndarray,
                 weights: np.ndarray | None = None) -> se2.Pose:
    """Minimise ``sum w_i (a_i^T x - b_i)^2`` over ``x = (t, cos, sin)`` on the circle.

    The cost is ``x^T M x - 2 m^T x + c`` with ``M = sum w a a^T``, ``m = sum w b a``;
    :func:`solve_normal_equations` finds its constrained minimum.
    """
    weighted = design if weights is None else design * weights[:, None]
    return solve_normal_equations(np.ascontiguousarray(weighted.T @ design),
                                  np.ascontiguousarray(weighted.T @ offset))


@numba.njit(cache=True, nogil=True)
def solve_normal_equations(big_m: np.ndarray, small_m: np.ndarray) -> np.ndarray:
    """Minimise ``x^T M x - 2 m^T x`` over ``x = (t_x, t_y, cos, sin)`` on the circle.

    Stationarity of ``x^T M x - 2 m^T x + lambda (x3^2 + x4^2 - 1)`` gives
    ``(M + lambda W) x = m`` (``W = diag(0, 0, 1, 1)``; Censi 2008, appendix).
    Eliminating ``t`` leaves ``(S + lambda I) r = h`` for ``r = (cos, sin)`` with the
    Schur complement ``S = D - B^T A^-1 B`` and ``h = m_r - B^T A^-1 m_t``; ``|r| = 1``
    becomes ``|adj(S + lambda I) h|^2 = det(S + lambda I)^2``, a quartic in lambda.
    Its largest real root makes ``S + lambda I`` positive semidefinite, which is the
    global minimum on the circle; the other real roots and the quartic's turning
    points are also scored, for safety (:func:`.plicp.quartic.quartic_candidates`).
    Returns the pose ``[t_x, t_y, theta]``.
    """
    a11, a12, b11, b12 = big_m[0, 0], big_m[0, 1], big_m[0, 2], big_m[0, 3]
    a22, b21, b22 = big_m[1, 1], big_m[1, 2], big_m[1, 3]
    d11, d12, d22 = big_m[2, 2], big_m[2, 3], big_m[3, 3]
    m1, m2, m3, m4 = small_m[0], small_m[1], small_m[2], small_m[3]
    ridge = TRANSLATION_RIDGE * (a11 + a22) + 1e-300
    a11, a22 = a11 + ridge, a22 + ridge
    det_a = a11 * a22 - a12 * a12
    i11, i12, i22 = a22 / det_a, -a12 / det_a, a11 / det_a
    # K = B^T A^-1 (2x2), S = D - K B, h = m_r - K m_t.
    k11, k12 = b11 * i11 + b21 * i12, b11 * i12 + b21 * i22
    k21, k22 = b12 * i11 + b22 * i12, b12 * i12 + b22 * i22
    s11 = d11 - (k11 * b11 + k12 * b21)
    s12 = d12 - (k11 * b12 + k12 * b22)
    s22 = d22 - (k21 * b12 + k22 * b22)
    h1 = m3 - (k11 * m1 + k12 * m2)
    h2 = m4 - (k21 * m1 + k22 * m2)
    scale = max(abs(s11), abs(s12), abs(s22), abs(h1), abs(h2), 1e-300)
    s11, s12, s22, h1, h2 = s11 / scale, s12 / scale, s22 / scale, h1 / scale, h2 / scale
    trace = s11 + s22
    det = s11 * s22 - s12 * s12
    # adj(S) h, with adj(S + lambda I) = adj(S) + lambda I for a 2x2 matrix.
    g1, g2 = s22 * h1 - s12 * h2, s11 * h2 - s12 * h1
    # Monic quartic lambda^4 + c1 lambda^3 + c2 lambda^2 + c3 lambda + c4.
    real = np.sort(quartic_candidates(
        2.0 * trace, trace * trace + 2.0 * det - (h1 * h1 + h2 * h2),
        2.0 * trace * det - 2.0 * (h1 * g1 + h2 * g2), det * det - (g1 * g1 + g2 * g2)))
    count = real.shape[0]
    best_c, best_s, best_cost = 1.0, 0.0, np.inf
    for order in range(count - 1, -1, -1):
        lam = real[order]
        # (S + lambda I) r = h by Cramer's rule, then projected onto the unit circle.
        e11, e22 = s11 + lam, s22 + lam
        det_e = e11 * e22 - s12 * s12
        if abs(det_e) <= 1e-14 * max(1.0, abs(e11), abs(e22), abs(s12)) ** 2:
            continue
        c, sn = (e22 * h1 - s12 * h2) / det_e, (e11 * h2 - s12 * h1) / det_e
        norm = math.hypot(c, sn)
        if norm == 0.0:
            continue
        c, sn = c / norm, sn / norm
        cost = s11 * c * c + 2.0 * s12 * c * sn + s22 * sn * sn - 2.0 * (h1 * c + h2 * sn)
        if cost < best_cost:
            best_c, best_s, best_cost = c, sn, cost
    r1, r2 = m1 - (b11 * best_c + b12 * best_s), m2 - (b21 * best_c + b22 * best_s)
    return np.array([i11 * r1 + i12 * r2, i12 * r1 + i22 * r2, math.atan2(best_s, best_c)])


@numba.njit(cache=True, nogil=True)
def iterate(table: np.ndarray, sorted_points: np.ndarray, bearings: np.ndarray,
            directions: np.ndarray, order: np.ndarray, points: np.ndarray, guess: np.ndarray,
            max_iterations: int, min_correspondences: int, coarse_keep_fraction: float,
            coarse_distance: float, coarse_step: float, max_distance: float,
            min_keep_fraction: float, max_keep_fraction: float, trim_sigma: float,
            huber_sigmas: float, convergence_translation: float,
            convergence_rotation: float) -> tuple:
    """Run PL-ICP iterations from ``guess`` (compiled; the loop of ``PlicpMatcher._run``).

    Each iteration pairs and trims (:func:`.plicp.segments.pair_and_trim`, the coarse
    phase with its wide gate and fixed keep fraction while a step still exceeds
    ``coarse_step``, then the fine phase adaptively) and takes the exact closed-form
    step. With ``huber_sigmas`` > 0 the fine phase begins with every pair, Huber
    weighted, and trims only once that fit settled: pairs that alone observe a
    direction (a corridor's door frames) move the estimate before their residuals are
    judged, instead of being trimmed for disagreeing with where it started. A phase
    ends on a step below the convergence thresholds or on a pairing (with its weights)
    seen before in it (the step depends only on them, so a repeat is a cycle - CSM's
    loop detection; the coarse phase once ran on to the cap in such a cycle, a 5 cm
    swing that never fell below ``coarse_step``: intel's keyframes 0.1 s apart, an
    in-place turn of 33 deg matched from the true step, unconverged at 0.07 m
    residual); the iteration cap ends all. Returns whether enough pairs were
    found, the estimate, whether it converged, the iterations, the last kept pairs
    (current indices, moved points, lines, segment ids, weights) and the last step.
    """
    estimate = guess.copy()
    hints = np.full(points.shape[0], -1, dtype=np.int64)  # nearest of the last iteration
    seen = np.zeros(max_iterations, dtype=np.uint64)  # pairings of the current phase
    seen_count = 0
    coarse = coarse_keep_fraction > 0.0
    weighted = huber_sigmas > 0.0  # the fine phase's weighted start is to come
    converged = False
    kept = np.zeros(0, dtype=np.int64)
    weight = np.zeros(0)
    moved = np.zeros((0, 2))
    line = np.zeros((0, 3))
    segment = np.zeros(0, dtype=np.int64)
    delta = np.zeros(3)
    iterations = 0
    for iterations in range(1, max_iterations + 1):
        kept, moved, line, segment, weight, big_m, small_m, signature, paired = pair_and_trim(
            table, sorted_points, bearings, directions, order, points, estimate,
            coarse_distance if coarse else max_distance,
            coarse_keep_fraction if coarse else -1.0,  # negative: adaptive trimming
            min_keep_fraction, max_keep_fraction, trim_sigma,
            huber_sigmas if weighted and not coarse else 0.0, hints)
        if paired < min_correspondences:
            return (False, estimate, False, iterations, kept, moved, line, segment, weight,
                    delta)
        delta = solve_normal_equations(big_m, small_m)
        updated = compose_poses(delta, estimate)
        step = relative_pose(estimate, updated)
        estimate = updated
        repeated = False
        for previous in seen[:seen_count]:
            repeated = repeated or previous == signature
        small = (is_small_step(step, coarse_step, coarse_step) if coarse else
                 is_small_step(step, convergence_translation, convergence_rotation))
        if small or repeated:  # the phase ends
            seen_count = 0
            if coarse:
                coarse = False
                continue
            if not weighted:
                converged = True
                break
            weighted = False  # settled on every pair: trim from here
            continue
        seen[seen_count] = signature
        seen_count += 1
    return True, estimate, converged, iterations, kept, moved, line, segment, weight, delta
