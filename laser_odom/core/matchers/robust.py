"""Robust weighting and trimming of residuals, shared by the matchers.

Weights follow iteratively reweighted least squares: a kernel rho(r) becomes the
weight w(r) = rho'(r) / r (Zhang, "Parameter estimation techniques", 1997).
"""

from __future__ import annotations

import math

import numba
import numpy as np

KERNELS = ('none', 'huber', 'cauchy', 'tukey')

HUBER = KERNELS.index('huber')
"""The Huber kernel's code in compiled code (:func:`kernel_weights`)."""


def robust_weights(residuals: np.ndarray, kernel: str, scale: float) -> np.ndarray:
    """Return IRLS weights in [0, 1] for ``residuals`` under ``kernel`` with ``scale``."""
    return kernel_weights(np.asarray(residuals, dtype=float), kernel_code(kernel),
                          float(scale))


def kernel_code(kernel: str) -> int:
    """Return the number compiled code knows ``kernel`` by (its place in KERNELS)."""
    if kernel not in KERNELS:
        raise ValueError(f'unknown robust kernel {kernel!r}; valid: {", ".join(KERNELS)}')
    return KERNELS.index(kernel)


@numba.njit(cache=True, nogil=True)
def kernel_weights(residuals: np.ndarray, code: int, scale: float) -> np.ndarray:
    """Compiled :func:`robust_weights`, the kernel given by :func:`kernel_code`.

    huber ``min(1, 1 / r)``, cauchy ``1 / (1 + r^2)``, tukey ``(1 - r^2)^2`` inside
    ``r < 1`` (else 0), with ``r = |residual| / scale``.
    """
    weights = np.ones(residuals.shape[0])
    for i in range(residuals.shape[0]):
        r = abs(residuals[i]) / max(scale, 1e-12)
        if code == 1:
            weights[i] = 1.0 if r <= 1.0 else 1.0 / max(r, 1e-12)
        elif code == 2:
            weights[i] = 1.0 / (1.0 + r * r)
        elif code == 3:
            weights[i] = (1.0 - r * r) ** 2 if r < 1.0 else 0.0
    return weights


@numba.njit(cache=True, nogil=True)
def trimmed_mask(residuals: np.ndarray, keep_fraction: float) -> np.ndarray:
    """Keep the ``keep_fraction`` smallest absolute residuals (trimmed ICP).

    Chetverikov et al., "The Trimmed Iterative Closest Point Algorithm", ICPR 2002.
    Exactly ``ceil(keep_fraction * n)`` are kept; among residuals equal to the last
    kept one, the earliest are.
    """
    n = residuals.shape[0]
    keep = int(math.ceil(min(max(keep_fraction, 0.0), 1.0) * n))
    if keep >= n:
        return np.ones(n, dtype=np.bool_)
    mask = np.zeros(n, dtype=np.bool_)
    if keep <= 0:
        return mask
    magnitude = np.abs(residuals)
    threshold = np.partition(magnitude, keep - 1)[keep - 1]  # O(n), no full sort
    mask[:] = magnitude < threshold
    ties = keep - int(np.count_nonzero(mask))
    for i in range(n):
        if ties <= 0:
            break
        if magnitude[i] == threshold:
            mask[i] = True
            ties -= 1
    return mask


@numba.njit(cache=True, nogil=True)
def inlier_mask(residuals: np.ndarray, min_fraction: float, sigmas: float) -> np.ndarray:
    """Keep the residuals within ``sigmas`` robust standard deviations, at least a share.

    Adaptive trimming (:func:`adaptive_keep_fraction`, sigma = 1.4826 MAD, up to all of
    them), keeping at least ``min_fraction``: in a corridor a single passer-by's legs
    would otherwise drag the weakly constrained axis.
    """
    return trimmed_mask(residuals, adaptive_keep_fraction(residuals, min_fraction, 1.0,
                                                          sigmas))


@numba.njit(cache=True, nogil=True)
def adaptive_keep_fraction(residuals: np.ndarray, min_fraction: float,
                           max_fraction: float, sigma_multiplier: float = 3.0) -> float:
    """Choose how many pairs to keep from the residual distribution itself.

    Keeps the pairs within ``sigma_multiplier`` robust standard deviations (from the
    median absolute residual, 1.4826 * MAD), clipped to [min_fraction, max_fraction]:
    a clean overlap keeps nearly all pairs, a scene with moving people or a changed
    door sheds the pairs that disagree.
    """
    if residuals.size == 0 or min_fraction >= max_fraction:
        return max_fraction  # nothing to choose: no need to sort
    sigma = robust_sigma(residuals)
    if sigma <= 0.0:
        return max_fraction
    fraction = np.count_nonzero(np.abs(residuals) <= sigma_multiplier * sigma) / residuals.size
    return min(max(fraction, min_fraction), max_fraction)


@numba.njit(cache=True, nogil=True)
def robust_sigma(residuals: np.ndarray) -> float:
    """Return the robust standard deviation of residuals, 1.4826 times their MAD."""
    return 1.4826 * median_magnitude(residuals)


@numba.njit(cache=True, nogil=True)
def median_magnitude(values: np.ndarray) -> float:
    """Return the median of ``|values|`` (a selection, not a sort).

    Compiled: called once or more per scan, numpy's own median spends some 20 us in
    Python per call on a few hundred values.
    """
    return np.median(np.abs(values))
