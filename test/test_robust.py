"""Robust weights and trimming shared by the matchers, value by value.

Each kernel's weight is checked against its definition (IRLS, w(r) = rho'(r) / r) at
chosen residuals, including the edges where a kernel changes branch; trimming keeps
exactly the smallest residuals; adaptive trimming keeps those within k robust sigmas.
"""

import math

import numpy as np
import pytest

from laser_odom.core.matchers.robust import (
    adaptive_keep_fraction, inlier_mask, kernel_code, KERNELS, median_magnitude,
    robust_weights, trimmed_mask)

RESIDUALS = np.array([0.0, 0.05, -0.1, 0.2, -0.3, 0.4])
"""Residuals [m] around the kernels' scale 0.2: r = 0, 0.25, 0.5, 1, 1.5, 2."""


def test_kernel_codes_follow_the_declared_names_and_refuse_others():
    assert [kernel_code(name) for name in KERNELS] == [0, 1, 2, 3]
    with pytest.raises(ValueError, match="unknown robust kernel 'l1'.*none, huber"):
        kernel_code('l1')


@pytest.mark.parametrize('kernel, expected', [
    ('none', [1.0, 1.0, 1.0, 1.0, 1.0, 1.0]),
    ('huber', [1.0, 1.0, 1.0, 1.0, 1.0 / 1.5, 0.5]),  # min(1, 1 / r)
    ('cauchy', [1.0, 1 / 1.0625, 0.8, 0.5, 1 / 3.25, 0.2]),  # 1 / (1 + r^2)
    ('tukey', [1.0, (1 - 0.0625) ** 2, 0.5625, 0.0, 0.0, 0.0]),  # (1 - r^2)^2, r < 1
])
def test_each_kernel_weighs_residuals_as_defined(kernel, expected):
    weights = robust_weights(RESIDUALS, kernel, 0.2)
    assert weights == pytest.approx(expected, rel=1e-12, abs=1e-15)


def test_tukey_rejects_at_its_scale_and_huber_starts_there():
    just_inside, just_outside = 0.2 * (1 - 1e-9), 0.2 * (1 + 1e-9)
    assert robust_weights(np.array([just_inside]), 'tukey', 0.2)[0] > 0.0
    assert robust_weights(np.array([0.2, just_outside]), 'tukey', 0.2).tolist() == [0.0, 0.0]
    assert robust_weights(np.array([just_outside]), 'huber', 0.2)[0] < 1.0


def test_a_zero_scale_does_not_divide_by_zero():
    weights = robust_weights(np.array([0.0, 1e-3]), 'huber', 0.0)
    assert weights[0] == 1.0 and 0.0 < weights[1] < 1e-8
    assert robust_weights(np.array([0.0]), 'cauchy', 0.0)[0] == 1.0


def test_trimming_keeps_exactly_the_smallest_and_the_earliest_ties():
    residuals = np.array([0.3, -0.1, 0.2, -0.2, 0.5, 0.2])
    assert trimmed_mask(residuals, 0.5).tolist() == [False, True, True, True, False, False]
    assert trimmed_mask(residuals, 1.0).all() and not trimmed_mask(residuals, 0.0).any()
    assert trimmed_mask(residuals, 0.01).tolist() == [False, True, False, False, False, False]
    assert trimmed_mask(residuals, 2.0).all() and not trimmed_mask(residuals, -1.0).any()
    # ceil: 4 of 6 for any share in (1/2, 2/3]
    assert trimmed_mask(residuals, 0.51).sum() == 4 and trimmed_mask(residuals, 2 / 3).sum() == 4
    assert trimmed_mask(np.zeros(0), 0.5).size == 0


@pytest.mark.parametrize('share', [0.1, 0.37, 0.5, 0.9, 0.999])
def test_trimming_a_large_set_keeps_the_smallest_ones(share):
    """Large enough that the partial sort leaves the rest unordered."""
    residuals = np.random.default_rng(7).normal(0.0, 1.0, 2000)
    mask = trimmed_mask(residuals, share)
    keep = math.ceil(share * residuals.size)
    assert mask.sum() == keep
    assert np.array_equal(np.flatnonzero(mask), np.sort(np.argsort(np.abs(residuals))[:keep]))


def test_trimming_with_every_residual_equal_keeps_the_first_ones():
    assert trimmed_mask(np.full(5, 0.1), 0.4).tolist() == [True, True, False, False, False]


def test_adaptive_trimming_keeps_the_residuals_within_k_robust_sigmas():
    residuals = np.array([0.3, -0.1, 0.2, -0.2, 0.5, 0.2])
    # 1.4826 * median |r| = 0.2965: 3 sigma keeps all; 0.5 sigma only |r| <= 0.148.
    assert adaptive_keep_fraction(residuals, 0.1, 1.0, 3.0) == 1.0
    assert adaptive_keep_fraction(residuals, 0.1, 1.0, 0.5) == pytest.approx(1 / 6)
    assert adaptive_keep_fraction(residuals, 0.5, 0.9, 0.5) == 0.5
    assert adaptive_keep_fraction(residuals, 0.1, 0.9, 3.0) == 0.9
    # median |r| 0.1: sigma 0.148; 2, 3 and 4 sigma keep 5, 6 and 7 of these 7
    assert adaptive_keep_fraction(np.array([0.1] * 5 + [0.4, -0.5]), 0.1, 1.0) == 6 / 7
    # exactly at k sigma counts as within: |r| = 0.2 = 0.2 / 0.2965 sigma
    assert adaptive_keep_fraction(residuals, 0.0, 1.0, 0.2 / 0.29652) == pytest.approx(4 / 6)
    assert adaptive_keep_fraction(np.zeros(0), 0.5, 0.9) == 0.9
    assert adaptive_keep_fraction(np.zeros(4), 0.1, 0.8) == 0.8  # sigma 0: nothing to judge
    assert adaptive_keep_fraction(np.array([0.0, 0.0, 0.0, 0.5, 1.0]), 0.1, 0.8) == 0.8
    assert adaptive_keep_fraction(residuals, 0.9, 0.9, 0.5) == 0.9


def test_inlier_mask_drops_the_outliers_but_keeps_a_minimum_share():
    rng = np.random.default_rng(4)
    residuals = np.concatenate((rng.normal(0.0, 0.01, 90), [0.5, -0.6, 0.7, 0.8, -0.9]))
    mask = inlier_mask(residuals, 0.5, 3.0)
    assert not mask[90:].any() and mask[:90].sum() >= 88
    kept = inlier_mask(residuals, 0.99, 3.0)
    assert kept.sum() == math.ceil(0.99 * residuals.size) and kept[:90].all()


def test_median_magnitude_is_the_median_of_the_absolute_values():
    assert median_magnitude(np.array([-3.0, 1.0, -2.0])) == 2.0
    assert median_magnitude(np.array([-4.0, 1.0, -2.0, 3.0])) == 2.5
