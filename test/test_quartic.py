"""PL-ICP's quartic: every real root and turning point, against numpy's eigenvalue roots."""

import numpy as np
import pytest

from laser_odom.core.matchers.plicp.quartic import quartic_candidates


def values(coefficients, x):
    """Return the monic quartic and its derivative at ``x``."""
    c1, c2, c3, c4 = coefficients
    return (np.polyval([1.0, c1, c2, c3, c4], x),
            np.polyval([4.0, 3.0 * c1, 2.0 * c2, c3], x))


def check_against_numpy(coefficients, tolerance=1e-9):
    """Every real root numpy finds is a candidate; every candidate is a root or a turn."""
    candidates = quartic_candidates(*coefficients)
    roots = np.roots([1.0, *coefficients])
    real = roots[np.abs(roots.imag) <= 1e-7 * np.maximum(1.0, np.abs(roots.real))].real
    scale = 1.0 + np.max(np.abs(coefficients))
    for root in real:
        assert np.min(np.abs(candidates - root)) <= tolerance * max(1.0, abs(root)), (
            coefficients, root, candidates)
    value, slope = values(coefficients, candidates)
    assert np.all((np.abs(value) <= 1e-9 * scale ** 4) | (np.abs(slope) <= 1e-9 * scale ** 3))
    return candidates


@pytest.mark.parametrize('seed', range(5))
def test_real_roots_agree_with_numpy(seed):
    rng = np.random.default_rng(seed)
    for _ in range(400):
        coefficients = rng.normal(0.0, 1.0, 4) * 10.0 ** rng.uniform(-3.0, 3.0, 4)
        check_against_numpy(coefficients)


@pytest.mark.parametrize('roots', [(-2.0, 1.0, 3.0, 5.0), (0.1, 0.1001, 0.1002, 7.0),
                                   (-1e3, -1.0, 1e-3, 1e3), (0.0, 0.0, 0.0, 0.0)])
def test_four_real_roots_are_each_found(roots):
    coefficients = np.poly(roots)[1:]
    candidates = check_against_numpy(coefficients, tolerance=1e-6)
    for root in roots:
        assert np.min(np.abs(candidates - root)) <= 1e-3 * max(1e-3, abs(root))


def test_a_double_root_is_a_candidate_even_where_rounding_lifts_it():
    """(l - 1)^2 (l^2 + 1): a touching root and two complex ones."""
    coefficients = np.poly([1.0, 1.0, 1j, -1j]).real[1:]
    candidates = quartic_candidates(*coefficients)
    assert np.min(np.abs(candidates - 1.0)) < 1e-7
    lifted = coefficients + np.array([0.0, 0.0, 0.0, 1e-12])  # no real root left
    assert np.min(np.abs(quartic_candidates(*lifted) - 1.0)) < 1e-5


def test_no_real_root_leaves_the_turning_points():
    """l^4 + 1 > 0 everywhere: its only turning point, 0, is the candidate."""
    assert np.allclose(quartic_candidates(0.0, 0.0, 0.0, 1.0), [0.0])


@pytest.mark.parametrize('bad', [np.nan, np.inf, -np.inf])
def test_coefficients_that_are_not_finite_raise(bad):
    with pytest.raises(ValueError, match='not finite'):
        quartic_candidates(1.0, bad, 0.0, 1.0)
