"""Real roots of the monic quartic of PL-ICP's closed-form step, without an eigensolver.

The Lagrange multiplier of Censi's step (:func:`.plicp.solver.solve_normal_equations`)
is a root of ``p(l) = l^4 + c1 l^3 + c2 l^2 + c3 l + c4``. The roots are isolated by
derivatives: between two consecutive real roots of ``p'`` the quartic is monotone, so
it has at most one root there, and a sign change brackets it; ``p'``'s roots are
isolated the same way by those of ``p''``, a quadratic solved in closed form. Each
bracketed root is polished by Newton's method kept inside its bracket (bisection when
a step leaves it), to the last bits. Every root lies within Cauchy's bound
``1 + max |c_k|``, and by Gauss-Lucas so do the derivatives' roots, which closes the
outer brackets. A few hundred floating-point operations: the companion matrix's
complex eigenvalues (what ``numpy.roots`` computes) cost ten times as much, and this
runs once per PL-ICP iteration.
"""

from __future__ import annotations

import math

import numba
import numpy as np

NEWTON_STEPS = 100
"""Iteration cap of one polished root (bisection alone halves the bracket each step,
so 100 reach the resolution of doubles from any bracket the bound gives)."""


@numba.njit(cache=True, nogil=True, inline='always')
def _monic(coefficients: np.ndarray, degree: int, x: float) -> float:
    """Return ``x^d + c[0] x^(d-1) + ... + c[d-1]`` (Horner)."""
    value = 1.0
    for k in range(degree):
        value = value * x + coefficients[k]
    return value


@numba.njit(cache=True, nogil=True, inline='always')
def _monic_slope(coefficients: np.ndarray, degree: int, x: float) -> float:
    """Return the derivative of :func:`_monic` at ``x``."""
    slope = float(degree)
    for k in range(degree - 1):
        slope = slope * x + (degree - 1 - k) * coefficients[k]
    return slope


@numba.njit(cache=True, nogil=True)
def _root_between(coefficients: np.ndarray, degree: int, low: float, high: float,
                  f_low: float) -> float:
    """Return the root of a monic polynomial in ``[low, high]``, where it changes sign once.

    Newton's method from the middle, each step replaced by the bracket's midpoint when
    it would leave the bracket (which shrinks around the root as values are seen).
    """
    x = 0.5 * (low + high)
    for _ in range(NEWTON_STEPS):
        value = _monic(coefficients, degree, x)
        if value == 0.0:
            return x
        if (value < 0.0) == (f_low < 0.0):
            low, f_low = x, value
        else:
            high = x
        slope = _monic_slope(coefficients, degree, x)
        step = x - value / slope if slope != 0.0 else 0.5 * (low + high)
        if not low < step < high:
            step = 0.5 * (low + high)
        if abs(step - x) <= 4e-16 * max(1.0, abs(x)):
            return step
        x = step
    return x


@numba.njit(cache=True, nogil=True)
def _roots_in(coefficients: np.ndarray, degree: int, breaks: np.ndarray, count: int,
              out: np.ndarray) -> int:
    """Write the roots of a monic polynomial between consecutive ``breaks`` into ``out``.

    The breaks (sorted, the outer two beyond every root) split the line where the
    polynomial is monotone; returns how many roots were written.
    """
    found = 0
    for k in range(count - 1):
        low, high = breaks[k], breaks[k + 1]
        f_low = _monic(coefficients, degree, low)
        if f_low == 0.0:
            out[found] = low
            found += 1
        elif f_low * _monic(coefficients, degree, high) < 0.0:
            out[found] = _root_between(coefficients, degree, low, high, f_low)
            found += 1
    return found


@numba.njit(cache=True, nogil=True)
def quartic_candidates(c1: float, c2: float, c3: float, c4: float) -> np.ndarray:
    """Return the real roots of ``l^4 + c1 l^3 + c2 l^2 + c3 l + c4``, then its turning points.

    The turning points (real roots of the derivative) follow the roots: where the
    quartic only touches zero - a double root, which rounding may lift just above the
    axis - the turning point is that root. The caller scores every candidate, so an
    extra one costs a score and a missed double root costs nothing. Raises ValueError
    on coefficients that are not finite.
    """
    if not (math.isfinite(c1) and math.isfinite(c2) and math.isfinite(c3)
            and math.isfinite(c4)):
        raise ValueError('PL-ICP step: the normal equations are not finite')
    bound = 1.0 + max(abs(c1), abs(c2), abs(c3), abs(c4))
    # p''(l) / 12 = l^2 + (c1 / 2) l + c2 / 6: closed form, cancellation-free.
    breaks = np.empty(4)
    count = 0
    breaks[count] = -bound
    count += 1
    half_b, c = 0.25 * c1, c2 / 6.0
    discriminant = half_b * half_b - c
    if discriminant >= 0.0:
        q = -(half_b + math.copysign(math.sqrt(discriminant), half_b))
        first, second = (q, c / q) if q != 0.0 else (0.0, 0.0)
        breaks[count], breaks[count + 1] = min(first, second), max(first, second)
        count += 2
    breaks[count] = bound
    count += 1
    for k in range(count):
        breaks[k] = min(max(breaks[k], -bound), bound)
    # p'(l) / 4 = l^3 + (3 c1 / 4) l^2 + (c2 / 2) l + c3 / 4.
    slope = np.array([0.75 * c1, 0.5 * c2, 0.25 * c3])
    turning = np.empty(5)
    turning[0] = -bound
    turns = _roots_in(slope, 3, breaks, count, turning[1:])
    turning[turns + 1] = bound
    quartic = np.array([c1, c2, c3, c4])
    out = np.empty(4 + turns)
    roots = _roots_in(quartic, 4, turning, turns + 2, out)
    out[roots:roots + turns] = turning[1:turns + 1]
    return out[:roots + turns]
