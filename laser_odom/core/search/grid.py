"""The reference scan as a smoothed likelihood grid, and the bound grids of the search.

Olson, "Real-time correlative scan matching", ICRA 2009, Sec. III: the reference scan is
rasterised once into a lookup table whose cells hold how likely a point observed there
is, ``exp(-d^2 / 2 sigma^2)`` with ``d`` the distance from the cell centre to the
reference surface; a pose is scored by summing the table over the current scan's
transformed points. For the branch and bound the table is max-filtered (Olson's
low-resolution table, Sec. IV; the precomputed grids of Hess et al., "Real-time loop
closure in 2D LIDAR SLAM", ICRA 2016, Sec. V-C): bound grid ``S`` holds in each cell
the largest fine value over the ``S x S`` cells from it upwards, so one lookup bounds
every lookup a point can make from a whole block of poses. The bound grids of all
the window sizes a search needs are stored end to end, so that every point of a
search node is bounded by one gather, each from the grid its own reach needs.

Values are quantised to ``uint8`` (0..255): sums of a few hundred of them are exact
integers, the tables are small and the maxima run on bytes.
"""

from __future__ import annotations

import math

import numba
import numpy as np

LIKELIHOOD_STEPS = 255
"""Quantisation of the likelihood: a cell holds ``round(255 exp(-d^2 / 2 sigma^2))``."""

KERNEL_SIGMAS = 3.0
"""The likelihood of a reference point is spread over this many sigmas (then ~1 %)."""


class LikelihoodGrid:
    """A square lattice of ``resolution`` cells over a region, holding likelihoods.

    Cell ``(i, j)`` (integers, possibly negative) is centred on ``(i, j) * resolution``
    in the reference frame; the fine table covers cells ``low`` .. ``low + shape - 1``,
    which holds every lookup the search makes. The bound grids extend by the largest
    window further up in each axis (zeros), so that no window runs off them.
    """

    def __init__(self, surface: np.ndarray, resolution: float, sigma: float,
                 low: np.ndarray, shape: tuple[int, int], windows: list[int]) -> None:
        """Rasterise ``surface`` (dense reference points, (N, 2)); build the ``windows``."""
        self.resolution = float(resolution)
        self.sigma = float(sigma)
        self.low = np.asarray(low, dtype=np.int64)
        self.windows = sorted({int(w) for w in windows} | {1})
        pad = self.windows[-1]
        self.shape = (int(shape[0]) + pad, int(shape[1]) + pad)
        self.cells = self.shape[0] * self.shape[1]
        fine = self._rasterise(np.asarray(surface, dtype=float), (int(shape[0]),
                                                                  int(shape[1])))
        self.tables = self._bounds(fine)
        self.start = {size: k * self.cells for k, size in enumerate(self.windows)}

    def _rasterise(self, surface: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """Return the fine table (padded to ``self.shape``).

        The surface is marked in its cells, then each cell takes the largest kernel
        value ``255 exp(-d^2 / 2 sigma^2)`` over the marked cells around it (``d``
        between cell centres): a grey dilation, one shifted maximum per kernel offset.
        Snapping the surface to cells costs at most half a cell, which the search's
        leaf spacing does anyway; the matcher refines.
        """
        table = np.zeros(self.shape, dtype=np.uint8)
        with np.errstate(invalid='ignore'):
            cells = np.rint(surface / self.resolution) - self.low
        inside = np.all((cells >= 0) & (cells < np.array(shape)), axis=1)
        cells = np.unique(cells[inside].astype(np.int64), axis=0)
        if len(cells) == 0:
            return table
        reach = int(math.ceil(KERNEL_SIGMAS * self.sigma / self.resolution))
        kernel = []
        for dx in range(-reach, reach + 1):
            for dy in range(-reach, reach + 1):
                squared = (dx * dx + dy * dy) * self.resolution ** 2
                weight = int(round(LIKELIHOOD_STEPS * math.exp(-0.5 * squared
                                                               / self.sigma ** 2)))
                if weight > 0:
                    kernel.append((dx, dy, weight))
        _dilate(table, cells, np.array(kernel, dtype=np.int64), shape[0], shape[1])
        return table

    def _bounds(self, fine: np.ndarray) -> np.ndarray:
        """Return the bound grid of every window size, flattened end to end.

        Powers of two are built by doubling, ``B_2S[c] = max(B_S[c], B_S[c + S])`` along
        each axis; any other size ``S`` from the largest power ``P <= S`` as
        ``max(B_P[c], B_P[c + S - P])`` (two overlapping windows cover it; the sparse
        table of range-maximum queries). Each costs a few passes over bytes.
        """
        powers = {1: fine}
        size = 1
        while 2 * size <= self.windows[-1]:
            powers[2 * size] = _widen(powers[size], size)
            size *= 2
        out = np.empty(len(self.windows) * self.cells, dtype=np.uint8)
        for k, window in enumerate(self.windows):
            power = 1 << (window.bit_length() - 1)
            table = powers[power] if power == window else _widen(powers[power],
                                                                 window - power)
            out[k * self.cells:(k + 1) * self.cells] = table.ravel()
        return out

    @property
    def fine(self) -> np.ndarray:
        """Return the fine table, flattened."""
        return self.tables[:self.shape[0] * self.shape[1]]

    def table_start(self, window: int) -> int:
        """Return where the bound grid of a window size starts in ``tables``."""
        return self.start[int(window)]

    def table_starts(self, windows: np.ndarray) -> np.ndarray:
        """Return where the bound grid of each window size starts (sizes among ``windows``)."""
        return np.searchsorted(self.windows, windows).astype(np.int64) * self.cells


@numba.njit(cache=True, nogil=True)
def _dilate(table: np.ndarray, cells: np.ndarray, kernel: np.ndarray, rows: int,
            columns: int) -> None:
    """Raise each cell within ``rows x columns`` to the kernel's weight from a marked cell.

    ``table[c + (dx, dy)] = max(table[c + (dx, dy)], w)`` for every marked cell ``c`` and
    kernel entry ``(dx, dy, w)``: the grey dilation of the marked cells.
    """
    for n in range(len(cells)):
        for m in range(len(kernel)):
            row, column = cells[n, 0] + kernel[m, 0], cells[n, 1] + kernel[m, 1]
            if 0 <= row < rows and 0 <= column < columns and table[row, column] < kernel[m, 2]:
                table[row, column] = kernel[m, 2]


def _widen(table: np.ndarray, shift: int) -> np.ndarray:
    """Return ``max(T[c], T[c + shift])`` along both axes.

    For a table of windows of size ``P >= shift`` that is the table of windows of size
    ``P + shift``.
    """
    wider = table.copy()
    np.maximum(wider[:-shift, :], table[shift:, :], out=wider[:-shift, :])
    taller = wider.copy()
    np.maximum(taller[:, :-shift], wider[:, shift:], out=taller[:, :-shift])
    return taller
