"""The polynomial bearings give the answers of ``math.atan2``, bit for bit."""

import math

import numpy as np

from laser_odom.core.scan.bearings import (
    approximate_atan2, ATAN2_ERROR, bearing_bin, bearing_place)


def _points(count: int, seed: int) -> np.ndarray:
    """Return directions of every octant at ranges from a millimetre to a kilometre."""
    rng = np.random.default_rng(seed)
    angle = rng.uniform(-math.pi, math.pi, count)
    radius = 10.0 ** rng.uniform(-3.0, 3.0, count)
    return np.column_stack((radius * np.cos(angle), radius * np.sin(angle)))


def test_the_approximation_stays_within_its_error_bound():
    points = _points(200_000, 1)
    # Near each octant's edges too, where the reduction changes branch.
    edges = np.array([[1.0, 1.0 + 1e-12], [1.0, 1.0 - 1e-12], [-1.0, 1e-300], [-1.0, -1e-300],
                      [1e-300, 1.0], [-1e-300, -1.0], [3.0, -3.0], [-2.0, 2.0]])
    worst = max(abs(approximate_atan2(y, x) - math.atan2(y, x))
                for x, y in np.vstack((points, edges)))
    assert worst <= ATAN2_ERROR
    assert worst > 0.01 * ATAN2_ERROR  # a polynomial, not atan2 itself


def test_axes_and_signed_zeros_are_atan2s_own():
    for x, y in ((0.0, 0.0), (-0.0, 0.0), (0.0, -0.0), (-0.0, -0.0), (-1.0, 0.0),
                 (-1.0, -0.0), (1.0, -0.0), (0.0, 2.0), (0.0, -2.0), (math.inf, 1.0),
                 (-math.inf, -1.0), (1.0, math.inf)):
        assert approximate_atan2(y, x) == math.atan2(y, x)
        assert math.copysign(1.0, approximate_atan2(y, x)) == math.copysign(1.0, math.atan2(y, x))
    assert math.isnan(approximate_atan2(math.nan, 1.0))


def _exact_bin(x: float, y: float, bin_angle: float, bins: int) -> int:
    return min(max(int((math.atan2(y, x) + math.pi) / bin_angle), 0), bins - 1)


def test_bins_are_those_of_atan2_even_on_their_edges():
    bin_angle = math.radians(0.25)
    bins = math.ceil(2.0 * math.pi / bin_angle)
    points = _points(100_000, 2)
    # Directions on the bin edges themselves, where the last digits decide the side.
    edge = -math.pi + bin_angle * np.arange(bins + 1)
    for scale in (0.37, 1.0, 23.0):
        points = np.vstack((points, scale * np.column_stack((np.cos(edge), np.sin(edge)))))
    decided = [bearing_bin(x, y, bin_angle, bins) for x, y in points]
    assert decided == [_exact_bin(x, y, bin_angle, bins) for x, y in points]


def test_places_are_those_of_atan2_along_the_sorted_bearings_themselves():
    reference = _points(2000, 3)
    bearings = np.sort(np.arctan2(reference[:, 1], reference[:, 0]))
    # Queries on the reference points' own rays (equal bearings) and between them.
    queries = np.vstack((reference * 1.7, reference * 0.3, _points(20_000, 4)))
    placed = [bearing_place(bearings, x, y) for x, y in queries]
    exact = [int(np.searchsorted(bearings, math.atan2(y, x))) for x, y in queries]
    assert placed == exact
    assert sum(exact[k] < len(bearings) and bearings[exact[k]] == math.atan2(y, x)
               for k, (x, y) in enumerate(queries)) > 1000  # ties were tested
