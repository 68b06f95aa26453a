"""Bearings at the price of a polynomial, with the answers of ``math.atan2`` (compiled).

The map's view and its free-space carving put every map cell in a bearing bin, and
the nearest-point search finds every query's place among the sorted bearings of its
reference, each ICP iteration again: ``atan2`` is the largest single cost of those
loops (about 25-28 ns a call here, against some 7 ns for a polynomial). Only a few
answers depend on a bearing's last digits, though - a bin is an integer, a place an
index - so each is computed from :func:`approximate_atan2`, whose error is bounded by
:data:`ATAN2_ERROR`, and ``math.atan2`` is called only when the approximate bearing
lies within that bound of a bin edge or of a sorted bearing. The results are those of
``math.atan2``, bit for bit; the shortcut changes the time, never an answer.
"""

from __future__ import annotations

import math

import numba
import numpy as np

ATAN_COEFFICIENTS = (0.9999993355810186, -0.33329860789834953, 0.1994656568667684,
                     -0.1390862964788629, 0.09642197448678323, -0.0559123272040005,
                     0.021862957576095656, -0.004054567008505229)
"""``atan(z) ~ z P(z^2)`` on [0, 1], ``P`` of degree 7 in ``z^2`` (near-minimax, fitted by
Lawson's iteration on Chebyshev nodes); its largest error on 2,000,001 points evenly
spread over [0, 1] is 3.75e-8 rad."""

ATAN2_ERROR = 1e-7
"""Bound [rad] on ``|approximate_atan2(y, x) - math.atan2(y, x)|``: the fit's measured
error and some margin (its rounding adds a few 1e-16); ``test_bearings`` checks it."""

_C0, _C1, _C2, _C3, _C4, _C5, _C6, _C7 = ATAN_COEFFICIENTS


@numba.njit(cache=True, nogil=True, inline='always')
def approximate_atan2(y: float, x: float) -> float:
    """Return ``atan2(y, x)`` within :data:`ATAN2_ERROR` (exact where ``x`` or ``y`` is 0).

    The octant reduction of every ``atan2``: ``z = min / max`` of ``|x|, |y|`` in
    [0, 1], ``atan(z)`` by :data:`ATAN_COEFFICIENTS`, then reflected into place. An
    axis (a zero, of either sign, or a NaN) goes to ``math.atan2``, which also keeps
    its signed-zero answers (``atan2(-0.0, -1) = -pi``).
    """
    ax, ay = abs(x), abs(y)
    if not (ax > 0.0 and ay > 0.0) or ax == math.inf or ay == math.inf:
        return math.atan2(y, x)
    z = min(ax, ay) / max(ax, ay)
    u = z * z
    r = z * (_C0 + u * (_C1 + u * (_C2 + u * (_C3 + u * (_C4 + u * (_C5 + u * (
        _C6 + u * _C7)))))))
    # Reflections as selects, not branches: the octants of a map's cells come in no order.
    r = 0.5 * math.pi - r if ay > ax else r
    r = math.pi - r if x < 0.0 else r
    return math.copysign(r, y)


@numba.njit(cache=True, nogil=True, inline='always')
def bearing_bin(qx: float, qy: float, bin_angle: float, bins: int) -> int:
    """Return ``int((math.atan2(qy, qx) + pi) / bin_angle)`` clipped to ``[0, bins)``.

    From :func:`approximate_atan2` unless the approximate value lies within
    :data:`ATAN2_ERROR` (in bins, with a margin for the division's rounding) of a bin
    edge, where the exact bearing decides.
    """
    position = (approximate_atan2(qy, qx) + math.pi) / bin_angle
    edge = 2.0 * ATAN2_ERROR / bin_angle + 1e-9 * (1.0 + abs(position))
    floor = math.floor(position)
    if position - floor <= edge or floor + 1.0 - position <= edge:
        position = (math.atan2(qy, qx) + math.pi) / bin_angle
    return min(max(int(position), 0), bins - 1)


@numba.njit(cache=True, nogil=True, inline='always')
def settled_place(bearings: np.ndarray, bearing: float, place: int) -> bool:
    """Tell whether ``place`` is the exact bearing's place, given an approximate ``bearing``.

    ``place`` is where ``bearing`` (within :data:`ATAN2_ERROR` of the exact one) sorts
    among ``bearings`` (the first position whose bearing is not below it). The exact
    bearing sorts there too unless a sorted bearing lies within the error bound of
    the approximate one - and any such bearing is a neighbour of ``place``.
    """
    n = bearings.shape[0]
    if place > 0 and bearings[place - 1] >= bearing - 2.0 * ATAN2_ERROR:
        return False
    return not (place < n and bearings[place] <= bearing + 2.0 * ATAN2_ERROR)


@numba.njit(cache=True, nogil=True, inline='always')
def bearing_place(bearings: np.ndarray, qx: float, qy: float) -> int:
    """Return ``np.searchsorted(bearings, math.atan2(qy, qx))`` (sorted ``bearings``)."""
    approximate = approximate_atan2(qy, qx)
    place = np.searchsorted(bearings, approximate)
    if settled_place(bearings, approximate, place):
        return place
    return np.searchsorted(bearings, math.atan2(qy, qx))
