"""Circular histograms: the wrapped copy gives every shift a circular kernel needs."""

import numpy as np
import pytest

from laser_odom.core.matchers.histograms import wrapped


@pytest.mark.parametrize('reach', [0, 1, 2, 5])
def test_the_wrapped_copy_holds_every_roll_within_its_reach(reach):
    values = np.random.default_rng(reach).random(36)
    padded = wrapped(values, reach)
    assert padded.shape == (36 + 2 * reach,)
    for shift in range(-reach, reach + 1):
        np.testing.assert_array_equal(padded[reach - shift:reach - shift + 36],
                                      np.roll(values, shift))


def test_the_matchers_histograms_are_smoothed_around_the_circle():
    # A single bin next to the wrap: the kernel's tails land on the far end, and the
    # sum is kept (nicp's [1, 4, 6, 4, 1] / 16, normalised).
    from laser_odom.core.matchers.nicp.surface import HISTOGRAM_BINS, orientation_histogram
    angle = -np.pi + 0.5 * (2.0 * np.pi / HISTOGRAM_BINS)  # the middle of bin 0
    smooth = orientation_histogram(np.array([[np.cos(angle), np.sin(angle)]]), np.ones(1))
    kernel = np.array([1.0, 4.0, 6.0, 4.0, 1.0])
    expected = np.zeros(HISTOGRAM_BINS)
    expected[[-2, -1, 0, 1, 2]] = kernel / np.linalg.norm(kernel)
    np.testing.assert_allclose(smooth, expected, atol=1e-15)
