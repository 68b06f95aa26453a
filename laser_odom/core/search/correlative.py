"""Correlative scan matching over a window of (x, y, theta), by exact branch and bound.

Olson, "Real-time correlative scan matching", ICRA 2009: score every pose of a window
by how well the current scan's points fall on the reference's likelihood grid
(:mod:`.grid`) and take the best, so the answer does not depend on a good initial
guess. Enumerating a window of +-1.5 m and +-90 deg at 0.1 m steps is ~3 x 10^5 poses
of ~150 points; instead the poses form a tree (:mod:`.tree`; Hess et al., ICRA 2016,
Sec. V): a node is a block of ``2^l`` rotations by ``2^l x 2^l`` translations, scored
against max-filtered grids that bound every pose in it, each point against the grid
its own rotational reach needs. Nodes are expanded breadth first, one vectorised
batch per level, and pruned when their bound is below ``keep_ratio`` times the best
exact score found (greedy dives find a good one early). Every pose scoring at least
``keep_ratio`` times the best therefore survives to the leaves (unless a level
exceeds ``MAX_NODES``, which the result reports), which yields both the global peak
and the best *distinct* alternative: how ambiguous the answer is.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
import time

import numpy as np

from laser_odom.core import se2
from laser_odom.core.scan.laser_scan import densify, ScanPoints
from laser_odom.core.search.grid import LIKELIHOOD_STEPS, LikelihoodGrid
from laser_odom.core.search.tree import SearchTree

RANGE_PERCENTILE = 95.0
"""Current points beyond this percentile of the ranges are left out of the search: the
farthest few would set a needlessly fine angular step (the matcher refines anyway)."""

MAX_REACH_CELLS = 400
"""Points farther than this many grid cells (40 m at 0.1 m) are not searched, so the
grid stays below ~10^6 cells and the angular step sensible whatever the scan holds."""

ANGLE_STEP_REACH = 10.0
"""The angular step moves a point this far [m] away by one cell: farther points are
scored a little off between leaf angles (the matcher refines), but the leaves do not
multiply with the range of the farthest wall."""

MAX_SEARCH_POINTS = 150
"""At most this many current points are scored (evenly thinned beyond it)."""

MIN_SEARCH_POINTS = 10
"""With fewer current points than this there is nothing to search with."""

MAX_NODES = 4000
"""Nodes kept at one level at most: the best-bounded ones. Where the scans share little
structure (a score landscape with no clear peak) the exact search would expand most of
the ~3e5 leaves; the cap bounds the time (~0.2 s at worst) and the result says it is
not exhaustive. On the real logs it binds in a third of the searches at 1 m / 20 deg
steps and costs no accuracy there."""

DIVES = 2
"""Greedy descents from the best nodes of each level, for an early exact score."""

SURFACE_GAP = 0.3
"""Reference beams closer than this [m] (or than 5 times the beam spacing at their
range) are joined into a surface when the grid is rasterised."""


@dataclass(frozen=True)
class SearchWindow:
    """The poses searched: ``guess`` +- ``linear`` [m] in x and y, +- ``angular`` [rad].

    ``resolution`` [m] is the translation step of the leaves and the grid's cell size;
    the angular step follows from it (one cell at the farthest point searched).
    ``sigma`` [m] is the width of the likelihood kernel (default: the resolution).
    """

    linear: float = 1.5
    angular: float = math.pi / 2
    resolution: float = 0.1
    sigma: float = 0.0

    @property
    def kernel_sigma(self) -> float:
        """Return the likelihood kernel width [m]."""
        return self.sigma if self.sigma > 0.0 else self.resolution


@dataclass
class SearchPeak:
    """A pose of the current scan in the reference frame and its score (0..1).

    The score is the mean likelihood of the current points at that pose: 1 when every
    point lies on the reference surface.
    """

    pose: np.ndarray
    score: float


@dataclass
class SearchResult:
    """Distinct peaks (best first), how ambiguous the best is, and what it cost.

    ``ambiguity`` is the score of the best pose distinct from the peak (farther than
    ``separation`` metres, rotation measured as the arc at the points' RMS range)
    divided by the peak's score; 0 when no pose outside the peak scores at least
    ``keep_ratio`` of it. ``nodes`` counts the scored tree nodes; ``grid_seconds`` and
    ``tree_seconds`` say where the time went (rasterising and bounding the reference,
    scoring the tree).
    """

    peaks: list[SearchPeak]
    ambiguity: float
    separation: float
    length_scale: float
    nodes: int
    points: int
    exhaustive: bool = True
    alternatives: list[SearchPeak] = field(default_factory=list)
    grid_seconds: float = 0.0
    tree_seconds: float = 0.0
    poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    """Every pose of the window scoring at least ``keep_ratio`` of the best (best first):
    the top of the score surface, from which its spread is measured."""
    scores: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """Their scores (0..1)."""

    @property
    def best(self) -> SearchPeak:
        """Return the best peak."""
        return self.peaks[0]


def search_points(current: ScanPoints, resolution: float) -> np.ndarray:
    """Return the current points the search scores: near ones, one per grid cell.

    Points beyond ``MAX_REACH_CELLS`` cells and beyond the 95th percentile of the
    ranges are dropped, the rest thinned to one per ``resolution`` cell (a dense wall
    would otherwise outvote everything else), then evenly to at most
    ``MAX_SEARCH_POINTS``.
    """
    points = current.points
    distance = np.hypot(points[:, 0], points[:, 1])
    near = distance <= MAX_REACH_CELLS * resolution
    points, distance = points[near], distance[near]
    if len(points) == 0:
        return points
    points = points[distance <= np.percentile(distance, RANGE_PERCENTILE)]
    cells = np.floor(points / resolution).astype(np.int64)
    _, first = np.unique(cells, axis=0, return_index=True)
    points = points[np.sort(first)]
    if len(points) > MAX_SEARCH_POINTS:
        points = points[np.linspace(0, len(points) - 1, MAX_SEARCH_POINTS).astype(int)]
    return points


def _grid_for(reference: ScanPoints, window: SearchWindow, tree: SearchTree) -> LikelihoodGrid:
    """Rasterise the reference over exactly the cells the search can look up."""
    resolution = window.resolution
    margin = int(math.ceil(float(tree.ranges.max()) / resolution)) + 1 + tree.max_dilation()
    low = tree.translation_low - margin
    size = tree.translations + 2 * margin
    spacing = 0.5 * min(resolution, window.kernel_sigma)
    surface = densify(reference, spacing, SURFACE_GAP, gap_per_range=5.0)
    return LikelihoodGrid(surface, resolution, window.kernel_sigma, low, (size, size),
                          sorted(tree.windows()))


KEEP_RATIO = 0.85
"""Nodes whose bound reaches this fraction of the best score are expanded, so the poses
that score almost as well as the peak - the candidates a matcher may prefer after
refining, and the evidence of ambiguity - are found too."""


def _branch_and_bound(tree: SearchTree, keep_ratio: float,
                      keep_margin: int = 0) -> tuple[np.ndarray, np.ndarray, bool]:
    """Return the leaves scoring at least ``keep_ratio`` of the best, and their scores.

    Leaves within ``keep_margin`` (in the tree's integer score units) of the best are
    kept too. Also returns whether the search was exhaustive (no level exceeded
    ``MAX_NODES``). Breadth first, one batch per level: nodes bounded below both
    ``keep_ratio`` times the best exact score found so far and that score less
    ``keep_margin`` are pruned, the rest split. Greedy dives from the best-bounded
    nodes of each level find a high exact score early.
    """
    nodes = tree.top_nodes()
    best = 0
    exhaustive = True
    values = np.zeros(0, dtype=np.int64)
    for level in range(tree.depth, -1, -1):
        values = tree.scores(level, nodes)
        if level == 0:
            best = max(best, int(values.max(initial=0)))
        else:
            for index in np.argsort(values)[::-1][:DIVES]:
                best = max(best, tree.dive(level, nodes[index]))
        keep = values >= min(keep_ratio * best, best - keep_margin)
        nodes, values = nodes[keep], values[keep]
        if len(nodes) > MAX_NODES:
            exhaustive = False
            top = np.argsort(values)[::-1][:MAX_NODES]
            nodes, values = nodes[top], values[top]
        if level > 0:
            nodes = tree.children(level, nodes)
    if best <= 0:
        return nodes[:0], values[:0], exhaustive
    return nodes, values, exhaustive


def search_tree(reference: ScanPoints, current: ScanPoints, guess: se2.Pose,
                window: SearchWindow) -> SearchTree | None:
    """Lay out the search of ``window`` around ``guess``: the leaves, the tree, the grid.

    None when either scan has too few points to score.
    """
    resolution = window.resolution
    points = search_points(current, resolution)
    if len(points) < MIN_SEARCH_POINTS or len(reference) < MIN_SEARCH_POINTS:
        return None
    reach = float(np.max(np.hypot(points[:, 0], points[:, 1])))
    angle_step = resolution / min(max(reach, resolution), ANGLE_STEP_REACH)
    half_angles = int(math.ceil(window.angular / angle_step))
    half_translations = int(math.ceil(window.linear / resolution))
    theta0 = float(guess[2]) - half_angles * angle_step
    translation_low = np.rint(np.asarray(guess[:2]) / resolution).astype(np.int64) \
        - half_translations
    tree = SearchTree(points, theta0, angle_step, 2 * half_angles + 1, translation_low,
                      2 * half_translations + 1, resolution)
    tree.grid = _grid_for(reference, window, tree)
    return tree


def correlative_search(reference: ScanPoints, current: ScanPoints, guess: se2.Pose,
                       window: SearchWindow, candidates: int = 3,
                       keep_ratio: float = KEEP_RATIO,
                       keep_margin: float = 0.0) -> SearchResult | None:
    """Find the best poses of ``current`` in ``reference``'s frame within the window.

    Returns up to ``candidates`` distinct peaks, best first, and the ambiguity of the
    best; None when either scan has too few points to score. Every pose scoring at
    least ``keep_ratio`` of the best, or within ``keep_margin`` (score units, 0..1) of
    it, is kept in the result (the top of the score surface).
    """
    started = time.perf_counter()
    tree = search_tree(reference, current, guess, window)
    if tree is None:
        return None
    gridded = time.perf_counter()
    margin = int(keep_margin * LIKELIHOOD_STEPS * len(tree.points))
    leaves, values, exhaustive = _branch_and_bound(tree, keep_ratio, margin)
    if len(leaves) == 0:
        return None

    order = np.argsort(values, kind='stable')[::-1]
    poses = tree.poses(leaves[order])
    scores = values[order] / (LIKELIHOOD_STEPS * len(tree.points))
    length_scale = float(np.sqrt(np.mean(np.sum(tree.points ** 2, axis=1))))
    separation = max(3.0 * window.resolution, 2.0 * window.kernel_sigma)
    peaks = distinct_peaks(poses, scores, separation, length_scale, max(candidates, 2))
    ambiguity = peaks[1].score / peaks[0].score if len(peaks) > 1 else 0.0
    return SearchResult(peaks=peaks[:max(candidates, 1)], ambiguity=float(ambiguity),
                        separation=separation, length_scale=length_scale,
                        nodes=tree.scored, points=len(tree.points), exhaustive=exhaustive,
                        alternatives=peaks[1:], grid_seconds=gridded - started,
                        tree_seconds=time.perf_counter() - gridded, poses=poses,
                        scores=scores)


def pose_distance(a: np.ndarray, b: np.ndarray, length_scale: float) -> np.ndarray:
    """Return ``max(|t_a - t_b|, L |theta_a - theta_b|)`` between poses (rows of a, b)."""
    a, b = np.atleast_2d(a), np.atleast_2d(b)
    translation = np.hypot(a[:, 0] - b[:, 0], a[:, 1] - b[:, 1])
    rotation = np.abs(se2.wrap_angle(a[:, 2] - b[:, 2])) * length_scale
    return np.maximum(translation, rotation)


def distinct_peaks(poses: np.ndarray, scores: np.ndarray, separation: float,
                   length_scale: float, count: int) -> list[SearchPeak]:
    """Return up to ``count`` peaks, best first, each farther than ``separation`` from the others.

    Greedy non-maximum suppression over poses sorted by score (best first).
    """
    peaks: list[SearchPeak] = []
    alive = np.ones(len(poses), dtype=bool)
    while len(peaks) < count and alive.any():
        index = int(np.flatnonzero(alive)[0])
        peaks.append(SearchPeak(poses[index].copy(), float(scores[index])))
        alive &= pose_distance(poses, poses[index], length_scale) > separation
    return peaks
