"""The search tree of the correlative search: nodes, their bounds, splitting, dives.

A node ``(j, i, k)`` at level ``l`` holds the leaf rotations ``j .. j + 2^l - 1`` and the
translations ``(i .. i + 2^l - 1) x (k .. k + 2^l - 1)`` (cells from the window's lower
corner), clipped to the window; the leaves (level 0) are single poses. Rotation and
translation halve together: the angular step moves a point 10 m away by one cell, so a
node's rotations move a typical indoor point by about as much as its translations do
(Hess et al., ICRA 2016, Sec. V, split translations only, under every rotation).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from laser_odom.core import se2
from laser_odom.core.search.grid import LikelihoodGrid


def coarsen(dilation: np.ndarray) -> np.ndarray:
    """Round dilations up to at most four values per octave (0..8, 10, 12, 14, 16, 20, ...).

    Bounds may only grow, and a few distinct window sizes keep the bound grids few.
    """
    dilation = np.asarray(dilation, dtype=np.int64)
    octave = np.floor(np.log2(np.maximum(dilation, 1))).astype(np.int64)
    step = np.where(dilation >= 8, 1 << np.maximum(octave - 2, 0), 1)
    return -(-dilation // step) * step


class SearchTree:
    """The search tree over one window: node scoring, children, greedy dives.

    A node ``(j, i, k)`` at level ``l`` holds the leaf rotations ``j .. j + 2^l - 1``
    and the translations ``(i .. i + 2^l - 1) x (k .. k + 2^l - 1)`` (in cells from
    ``translation_low``), clipped to the window.
    """

    def __init__(self, points: np.ndarray, theta0: float, angle_step: float, angles: int,
                 translation_low: np.ndarray, translations: int, resolution: float) -> None:
        self.points = points
        self.ranges = np.hypot(points[:, 0], points[:, 1])
        self.theta0, self.angle_step, self.angles = theta0, angle_step, angles
        self.translation_low, self.translations = translation_low, translations
        self.resolution = resolution
        self.depth = int(math.ceil(math.log2(translations))) if translations > 1 else 0
        # A point at range r moves at most r * half_width under a node's rotations, plus
        # one cell for rounding both positions to cells; none at a leaf's exact angle.
        self.dilation = [np.zeros(len(points), dtype=np.int64)] + [
            coarsen(np.ceil(self.ranges * 0.5 * (2 ** level - 1) * angle_step
                            / resolution).astype(np.int64) + 1)
            for level in range(1, self.depth + 1)]
        self.grid: LikelihoodGrid | None = None
        self._shift: dict[int, np.ndarray] = {}
        self._rotated: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}
        self.scored = 0

    def windows(self) -> set[int]:
        """Return every lookup window size (cells) the nodes need."""
        return {2 ** level + 2 * int(m) for level, dilation in enumerate(self.dilation)
                for m in np.unique(dilation)}

    def max_dilation(self) -> int:
        """Return the largest dilation (cells) of any point at any level."""
        return int(max(int(d.max(initial=0)) for d in self.dilation))

    def shift(self, level: int) -> np.ndarray:
        """Return each point's flat offset to its bound grid's window corner."""
        shift = self._shift.get(level)
        if shift is None:
            grid = self.grid
            dilation = self.dilation[level]
            start = grid.table_starts(2 ** level + 2 * dilation)
            shift = start - dilation * grid.shape[1] - dilation
            self._shift[level] = shift
        return shift

    def poses(self, leaves: np.ndarray) -> np.ndarray:
        """Return the poses ``[x, y, theta]`` of leaves ``(j, i, k)``."""
        return np.column_stack((
            (self.translation_low[0] + leaves[:, 1]) * self.resolution,
            (self.translation_low[1] + leaves[:, 2]) * self.resolution,
            se2.wrap_angle(self.theta0 + leaves[:, 0] * self.angle_step)))

    def leaves(self) -> np.ndarray:
        """Return every leaf ``(j, i, k)`` of the window (for exhaustive checks)."""
        j, i, k = np.meshgrid(np.arange(self.angles), np.arange(self.translations),
                              np.arange(self.translations), indexing='ij')
        return np.column_stack((j.ravel(), i.ravel(), k.ravel()))

    def top_nodes(self) -> np.ndarray:
        """Return the nodes of the top level: every angle block, one translation block."""
        starts = np.arange(0, self.angles, 2 ** self.depth)
        return np.column_stack((starts, np.zeros_like(starts), np.zeros_like(starts)))

    def scores(self, level: int, nodes: np.ndarray) -> np.ndarray:
        """Return the bound (level > 0) or exact score (level 0) of nodes ``(j, i, k)``.

        A node's rotations are scored at their middle angle; each point then lies
        within its dilation of where any of them puts it, so its lookup in the bound
        grid whose window spans the translation block plus twice the dilation bounds
        every leaf of the node. Each angle block's rotated points are computed once
        per search, when a node first needs them (:func:`_node_scores`).
        """
        grid = self.grid
        self.scored += len(nodes)
        cosines, sines, bases, known = self._rotations(level)
        return _node_scores(grid.tables, self.points, cosines, sines, 2 ** level,
                            grid.resolution, self.translation_low - grid.low, grid.shape[1],
                            self.shift(level), np.ascontiguousarray(nodes, dtype=np.int64),
                            bases, known)

    def _rotations(self, level: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Return the middle angle's cosine and sine of each angle block of a level.

        With them the lookup bases of the block's points (filled as the blocks are
        first scored) and which blocks have theirs.
        """
        rotations = self._rotated.get(level)
        if rotations is None:
            block = 2 ** level
            starts = np.arange(0, self.angles, block)
            last = np.minimum(starts + block, self.angles) - 1
            centre = self.theta0 + 0.5 * (starts + last) * self.angle_step
            rotations = (np.cos(centre), np.sin(centre),
                         np.empty((len(starts), len(self.points)), dtype=np.int64),
                         np.zeros(len(starts), dtype=np.bool_))
            self._rotated[level] = rotations
        return rotations

    def children(self, level: int, nodes: np.ndarray) -> np.ndarray:
        """Return the nodes one level down that split these, inside the window."""
        return _children(np.ascontiguousarray(nodes, dtype=np.int64), 1 << (level - 1),
                         self.angles, self.translations)

    def dive(self, level: int, node: np.ndarray) -> int:
        """Descend greedily from ``node`` to a leaf; return the leaf's exact score."""
        node = node[None, :]
        score = 0
        while level > 0:
            kids = self.children(level, node)
            level -= 1
            values = self.scores(level, kids)
            best = int(np.argmax(values))
            node, score = kids[best:best + 1], int(values[best])
        return score


@numba.njit(cache=True, nogil=True)
def _node_scores(tables: np.ndarray, points: np.ndarray, cosines: np.ndarray,
                 sines: np.ndarray, block: int, resolution: float, corner: np.ndarray,
                 width: int, shift: np.ndarray, nodes: np.ndarray, bases: np.ndarray,
                 known: np.ndarray) -> np.ndarray:
    """Return ``sum_p tables[base(j, p) + i * width + k]`` for every node ``(j, i, k)``.

    The hot loop of the search (a third to a half of a step's time with ``prior:
    none``). ``base(j, p)`` is where point ``p`` rotated by the middle angle of the
    node's angle block ``j // block`` falls in the fine table (its cell from the
    window's lower corner, ``corner`` in table cells), plus its bound grid's ``shift``;
    each block's bases are computed the first time a node needs them and kept in
    ``bases`` (``known`` marks them) for the rest of the search.
    """
    scores = np.empty(len(nodes), dtype=np.int64)
    for n in range(len(nodes)):
        angle = nodes[n, 0] // block
        if not known[angle]:
            c, s = cosines[angle], sines[angle]
            for p in range(len(points)):
                x, y = points[p, 0], points[p, 1]
                row = np.int64(np.rint((c * x - s * y) / resolution)) + corner[0]
                column = np.int64(np.rint((s * x + c * y) / resolution)) + corner[1]
                bases[angle, p] = row * width + column + shift[p]
            known[angle] = True
        offset = nodes[n, 1] * width + nodes[n, 2]
        total = 0
        for p in range(len(points)):
            total += tables[bases[angle, p] + offset]
        scores[n] = total
    return scores


@numba.njit(cache=True, nogil=True)
def _children(nodes: np.ndarray, half: int, angles: int, translations: int) -> np.ndarray:
    """Return the eight octants of each node (its block halved), those inside the window.

    In the order of the nodes, each node's octants by angle, then x, then y.
    """
    kids = np.empty((8 * len(nodes), 3), dtype=np.int64)
    count = 0
    for n in range(len(nodes)):
        for a in (0, half):
            for b in (0, half):
                for c in (0, half):
                    j, i, k = nodes[n, 0] + a, nodes[n, 1] + b, nodes[n, 2] + c
                    if j < angles and i < translations and k < translations:
                        kids[count, 0], kids[count, 1], kids[count, 2] = j, i, k
                        count += 1
    return kids[:count]
