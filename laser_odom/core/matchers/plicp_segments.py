"""PL-ICP's view of the reference scan: segments between beam-order neighbours.

Censi, "An ICP variant using a point-to-line metric", ICRA 2008, Sec. III: a current
point is paired with the segment between its nearest reference point ``j1`` and the
closer of ``j1``'s neighbours in the scan's beam order, and its error is the distance
to the line through that segment. Everything per reference scan is computed once and
cached in ``ScanPoints.cache`` (a scan is the current scan once and the reference
once), so an iteration costs one nearest-neighbour search in the reference's bearing
index and one table lookup, compiled into one kernel with the trimming and the normal
equations (:func:`pair_and_trim`).
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numba
import numpy as np

from laser_odom.core.matchers.robust import adaptive_keep_fraction, trimmed_mask
from laser_odom.core.nearest import BearingIndex, nearest_by_bearing
from laser_odom.core.scan import ScanPoints


@dataclass
class ReferenceSegments:
    """Per-reference-scan segment table, cached in ``ScanPoints.cache``.

    Row ``j`` (one per reference point, plus a last all-zero row that stands for "no
    neighbour found") holds what pairing a point with ``j`` needs, so one fancy index
    per iteration fetches it all (columns in ``TABLE_COLUMNS`` order):
    ``u, c``: the point ``p`` is closer to ``j + 1`` than to ``j - 1`` iff
    ``p . u < c`` (``u = r[j-1] - r[j+1]``, ``c = (|r[j-1]|^2 - |r[j+1]|^2) / 2``;
    forced to the only side that forms a segment); the unit normal and line offset
    ``n . r[j]`` of segment ``(j-1, j)``, then of ``(j, j+1)``; and whether ``j`` forms
    any segment at all. ``surface_normals`` (one per point) are the normals of the
    surface around each point for the information matrix (:func:`surface_normals`).
    """

    table: np.ndarray
    segment_ok: np.ndarray
    surface_normals: np.ndarray


TABLE_COLUMNS = ('ux', 'uy', 'c', 'prev_nx', 'prev_ny', 'prev_offset', 'next_nx', 'next_ny',
                 'next_offset', 'usable')


def reference_segments(reference: ScanPoints, max_beam_gap: int,
                       max_segment_length: float,
                       information_window: float = 1.0) -> ReferenceSegments:
    """Return the segments between beam-order neighbours of a reference scan (cached).

    Two consecutive valid points form a segment only if their beams are at most
    ``max_beam_gap`` apart (a few dropped readings) and the points are at most
    ``max_segment_length`` apart: a larger jump is a range discontinuity (an occluding
    edge, a doorway), and the line between its ends lies on no surface.
    """
    key = ('plicp_segments', int(max_beam_gap), float(max_segment_length),
           float(information_window))
    cached = reference.cache.get(key)
    if cached is not None:
        return cached
    pts = reference.points
    n = pts.shape[0]
    delta = np.diff(pts, axis=0)
    length = np.hypot(delta[:, 0], delta[:, 1])
    ok = ((np.diff(reference.beam_index) <= max_beam_gap) & (length <= max_segment_length)
          & (length > 0.0))
    safe = np.where(ok, length, 1.0)
    seg_normals = np.column_stack((-delta[:, 1] / safe, delta[:, 0] / safe))
    seg_normals[~ok] = 0.0
    prev_ok = np.concatenate(([False], ok))
    next_ok = np.concatenate((ok, [False]))
    zero = np.zeros((1, 2))
    prev_n = np.vstack((zero, seg_normals))
    next_n = np.vstack((seg_normals, zero))
    padded = np.vstack((pts[:1], pts, pts[-1:]))
    before, after = padded[:-2], padded[2:]
    table = np.zeros((n + 1, len(TABLE_COLUMNS)))
    table[:n, 0:2] = before - after
    table[:n, 2] = 0.5 * (np.sum(before ** 2, axis=1) - np.sum(after ** 2, axis=1))
    only_next = next_ok & ~prev_ok
    only_prev = prev_ok & ~next_ok
    table[:n, 0:2][only_next | only_prev] = 0.0
    table[:n, 2][only_next] = 1.0
    table[:n, 2][only_prev] = -1.0
    table[:n, 3:5] = prev_n
    table[:n, 5] = np.sum(prev_n * pts, axis=1)
    table[:n, 6:8] = next_n
    table[:n, 8] = np.sum(next_n * pts, axis=1)
    table[:n, 9] = prev_ok | next_ok
    result = ReferenceSegments(table, ok, surface_normals(pts, length, ok,
                                                          information_window))
    reference.cache[key] = result
    return result


def surface_normals(points: np.ndarray, length: np.ndarray, segment_ok: np.ndarray,
                    window: float) -> np.ndarray:
    """Return the normal of the line fitted to each point's surface within ``window`` [m].

    A two-point segment's normal carries the range noise of both ends (1 cm over a
    1 cm beam spacing tilts it by tens of degrees), so information computed with it
    would claim that the axis of a featureless corridor is constrained. For the
    information matrix each point instead gets the normal of the total-least-squares
    line through the points of its surface run (consecutive segments) within
    ``window / 2`` of arc length on either side; window sums come from cumulative
    sums, so all points cost O(n). Points with fewer than 3 such points keep a zero
    normal (they add no information).
    """
    n = points.shape[0]
    if n < 3:
        return np.zeros((n, 2))
    # Arc length along the scan; a break between runs counts as an unbridgeable jump.
    arc = np.concatenate(([0.0], np.cumsum(np.where(segment_ok, length, 1e9))))
    lo = np.searchsorted(arc, arc - 0.5 * window, side='left')
    hi = np.searchsorted(arc, arc + 0.5 * window, side='right')
    x, y = points[:, 0], points[:, 1]
    sums = np.zeros((n + 1, 5))
    np.cumsum(np.column_stack((x, y, x * x, x * y, y * y)), axis=0, out=sums[1:])
    window_sums = sums[hi] - sums[lo]
    count = (hi - lo).astype(float)
    mean_x, mean_y = window_sums[:, 0] / count, window_sums[:, 1] / count
    cxx = window_sums[:, 2] / count - mean_x * mean_x
    cxy = window_sums[:, 3] / count - mean_x * mean_y
    cyy = window_sums[:, 4] / count - mean_y * mean_y
    direction = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)
    normals = np.column_stack((-np.sin(direction), np.cos(direction)))
    normals[count < 3] = 0.0
    return normals


@dataclass
class Pairs:
    """Trimmed point-to-line pairs of one iteration.

    ``points`` are the paired current points moved by the estimate, ``normals`` and
    ``offset`` their lines ``n . x = n . q``; ``nearest`` is each pair's nearest
    reference point ``j1``; ``normal_matrix`` and ``normal_vector`` are ``M`` and ``m``
    of the closed-form step (:func:`.plicp_solver.solve_normal_equations`);
    ``signature`` identifies the pairing.
    """

    points: np.ndarray
    normals: np.ndarray
    nearest: np.ndarray
    normal_matrix: np.ndarray
    normal_vector: np.ndarray
    offset: np.ndarray
    signature: int

    def __len__(self) -> int:
        """Return the number of pairs."""
        return int(self.points.shape[0])


def pair_with_segments(segments: ReferenceSegments, index: BearingIndex, moved: np.ndarray,
                       max_distance: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pair moved current points with reference segments (Censi 2008, Sec. III).

    Each point's nearest reference point ``j1`` (within ``max_distance``) is found in
    the reference's bearing index; the segment goes to whichever of ``j1 - 1`` /
    ``j1 + 1`` is closer to the point, among those that form a segment with ``j1``.
    Returns the indices of the paired current points, their segment ids
    (``2 j1 + side``) and their lines ``(n_x, n_y, n . q)``.
    """
    paired, segment_id, line = _pair(segments.table, index.sorted_points, index.bearings,
                                     index.directions, index.order,
                                     np.ascontiguousarray(moved, dtype=float),
                                     float(max_distance))
    return paired, segment_id, line


@numba.njit(cache=True, nogil=True)
def _pair(table: np.ndarray, sorted_points: np.ndarray, bearings: np.ndarray,
          directions: np.ndarray, order: np.ndarray, moved: np.ndarray, max_distance: float
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Compiled kernel of :func:`pair_with_segments`."""
    _, nearest = nearest_by_bearing(sorted_points, bearings, directions, order, moved,
                                    max_distance)
    count = moved.shape[0]
    paired = np.empty(count, dtype=np.int64)
    segment_id = np.empty(count, dtype=np.int64)
    line = np.empty((count, 3))
    k = 0
    for i in range(count):
        row = table[nearest[i]]
        if row[9] == 0.0:
            continue
        use_next = moved[i, 0] * row[0] + moved[i, 1] * row[1] < row[2]
        first = 6 if use_next else 3
        paired[k] = i
        segment_id[k] = 2 * nearest[i] + (1 if use_next else 0)
        line[k, 0], line[k, 1], line[k, 2] = row[first], row[first + 1], row[first + 2]
        k += 1
    return paired[:k], segment_id[:k], line[:k]


@numba.njit(cache=True, nogil=True)
def pair_and_trim(table: np.ndarray, sorted_points: np.ndarray, bearings: np.ndarray,
                  directions: np.ndarray, order: np.ndarray, points: np.ndarray,
                  estimate: np.ndarray, max_distance: float, keep_fraction: float,
                  min_keep_fraction: float, max_keep_fraction: float,
                  trim_sigma: float) -> tuple:
    """One PL-ICP pairing: move, pair, trim, and sum the normal equations (compiled).

    ``points`` are moved by ``estimate`` and paired (:func:`pair_with_segments`);
    the pairs with the smallest point-to-line residuals are kept - a fixed
    ``keep_fraction``, or when it is negative the adaptive fraction
    (:func:`adaptive_keep_fraction`). Returns the kept current-point indices, their
    moved points, lines ``(n_x, n_y, n . q)`` and segment ids, the normal equations
    ``M = sum a a^T``, ``m = sum (n . q) a`` of the closed-form step
    (``a = (n_x, n_y, n . p, n x p)``, :func:`.plicp_solver.solve_normal_equations`),
    and a hash of the pairing (equal pairings give equal steps: a repeat is a cycle).
    """
    c, s = math.cos(estimate[2]), math.sin(estimate[2])
    moved = np.empty_like(points)
    moved[:, 0] = c * points[:, 0] - s * points[:, 1] + estimate[0]
    moved[:, 1] = s * points[:, 0] + c * points[:, 1] + estimate[1]
    paired, segment_id, line = _pair(table, sorted_points, bearings, directions, order,
                                     moved, max_distance)
    count = paired.shape[0]
    residuals = np.empty(count)
    for k in range(count):
        p = moved[paired[k]]
        residuals[k] = line[k, 0] * p[0] + line[k, 1] * p[1] - line[k, 2]
    if keep_fraction < 0.0:
        keep_fraction = adaptive_keep_fraction(residuals, min_keep_fraction,
                                               max_keep_fraction, trim_sigma)
    mask = trimmed_mask(residuals, keep_fraction)
    kept = np.flatnonzero(mask)
    big_m = np.zeros((4, 4))
    small_m = np.zeros(4)
    row = np.empty(4)
    signature = np.uint64(14695981039346656037)
    for k in kept:
        p = moved[paired[k]]
        nx, ny = line[k, 0], line[k, 1]
        row[0], row[1] = nx, ny
        row[2], row[3] = nx * p[0] + ny * p[1], ny * p[0] - nx * p[1]
        for a in range(4):
            small_m[a] += row[a] * line[k, 2]
            for b in range(4):
                big_m[a, b] += row[a] * row[b]
        for value in (paired[k], segment_id[k]):  # FNV-1a over the pairing
            signature = (signature ^ np.uint64(value)) * np.uint64(1099511628211)
    return (paired[kept], moved[paired[kept]], line[kept], segment_id[kept], big_m, small_m,
            signature, count)
