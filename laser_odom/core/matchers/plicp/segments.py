"""PL-ICP's view of the reference scan: segments between beam-order neighbours.

Censi, "An ICP variant using a point-to-line metric", ICRA 2008, Sec. III: a current
point is paired with the segment between its nearest reference point ``j1`` and the
closer of ``j1``'s neighbours in the scan's beam order, and its error is the distance
to the line through that segment. The line's direction is fitted to the surface around
the segment (``segment_window``), not taken from its two ends alone
(:func:`_fit_segment_lines`). Everything per reference scan is computed once and
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

from laser_odom.core.matchers.robust import (
    adaptive_keep_fraction, HUBER, kernel_weights, robust_sigma, trimmed_mask)
from laser_odom.core.scan.laser_scan import ScanPoints
from laser_odom.core.scan.nearest import BearingIndex, nearest_by_bearing
from laser_odom.core.se2 import move_points


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
                       max_segment_length: float, information_window: float = 1.0,
                       segment_window: float = 0.0) -> ReferenceSegments:
    """Return the segments between beam-order neighbours of a reference scan (cached).

    Two consecutive valid points form a segment only if their beams are at most
    ``max_beam_gap`` apart (a few dropped readings) and the points are at most
    ``max_segment_length`` apart: a larger jump is a range discontinuity (an occluding
    edge, a doorway), and the line between its ends lies on no surface. With
    ``segment_window`` > 0 a real scan's segment lines take the direction of the
    surface fitted over that length around them (:func:`_fit_segment_lines`); a
    virtual scan of the local map (``reference.virtual``) already lies on fitted
    surfaces and keeps its segments.
    """
    if reference.virtual:
        segment_window = 0.0
    key = ('plicp_segments', int(max_beam_gap), float(max_segment_length),
           float(information_window), float(segment_window))
    cached = reference.cache.get(key)
    if cached is not None:
        return cached
    points = np.ascontiguousarray(reference.points, dtype=float).reshape(-1, 2)
    table, ok, length = _segment_table(points, np.asarray(reference.beam_index, np.int64),
                                       int(max_beam_gap), float(max_segment_length))
    if segment_window > 0.0:
        _fit_segment_lines(table, points, ok,
                           surface_normals(points, length, ok, segment_window))
    result = ReferenceSegments(table, ok, surface_normals(points, length, ok,
                                                          information_window))
    reference.cache[key] = result
    return result


@numba.njit(cache=True, nogil=True)
def _segment_table(points: np.ndarray, beam_index: np.ndarray, max_beam_gap: int,
                   max_segment_length: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Compiled body of :func:`reference_segments`: the table, segment flags, lengths.

    Segment ``j`` joins points ``j`` and ``j + 1``; its unit normal is the segment
    direction turned by +90 deg, its line offset ``n . r``. Row ``j`` of the table
    holds the bisector test against ``r[j-1]`` and ``r[j+1]`` (forced to the only
    side with a segment) and both adjacent lines (zero where there is no segment).
    """
    n = points.shape[0]
    segments = max(n - 1, 0)
    length = np.zeros(segments)
    ok = np.zeros(segments, dtype=np.bool_)
    normal = np.zeros((segments, 2))
    for j in range(segments):
        dx, dy = points[j + 1, 0] - points[j, 0], points[j + 1, 1] - points[j, 1]
        length[j] = math.hypot(dx, dy)
        ok[j] = (beam_index[j + 1] - beam_index[j] <= max_beam_gap
                 and 0.0 < length[j] <= max_segment_length)
        if ok[j]:
            normal[j, 0], normal[j, 1] = -dy / length[j], dx / length[j]
    table = np.zeros((n + 1, len(TABLE_COLUMNS)))
    for j in range(n):
        before, after = max(j - 1, 0), min(j + 1, n - 1)
        prev_ok = j > 0 and ok[j - 1]
        next_ok = j < segments and ok[j]
        if prev_ok and not next_ok:
            table[j, 2] = -1.0
        elif next_ok and not prev_ok:
            table[j, 2] = 1.0
        else:
            table[j, 0] = points[before, 0] - points[after, 0]
            table[j, 1] = points[before, 1] - points[after, 1]
            table[j, 2] = 0.5 * ((points[before, 0] ** 2 + points[before, 1] ** 2)
                                 - (points[after, 0] ** 2 + points[after, 1] ** 2))
        if prev_ok:
            table[j, 3], table[j, 4] = normal[j - 1, 0], normal[j - 1, 1]
            table[j, 5] = normal[j - 1, 0] * points[j, 0] + normal[j - 1, 1] * points[j, 1]
        if next_ok:
            table[j, 6], table[j, 7] = normal[j, 0], normal[j, 1]
            table[j, 8] = normal[j, 0] * points[j, 0] + normal[j, 1] * points[j, 1]
        table[j, 9] = 1.0 if prev_ok or next_ok else 0.0
    return table, ok, length


@numba.njit(cache=True, nogil=True)
def _fit_segment_lines(table: np.ndarray, points: np.ndarray, segment_ok: np.ndarray,
                       fitted: np.ndarray) -> None:
    """Turn each segment's line to the direction of its fitted surface (in place).

    The direction of a two-point segment carries the range noise of both ends: 2 cm
    of noise over a 6 cm beam spacing (a 0.33 deg scanner at 10 m) tilts it by tens of
    degrees, so along a direction the scene barely constrains (between two long walls)
    every tilted segment pulls a little, and PL-ICP stops wherever the pulls cancel:
    in the simulated campus it went 0.43 m from the true step when started on it, and
    did not move when started 2 cm from it. The line through the segment's midpoint along
    the mean of its ends' ``fitted`` surface normals (:func:`surface_normals`; one
    end's where the other has none, the segment's own where neither has) has one
    minimum there. Measured with plicp, scan to scan (with the coarse phase's cycle
    check and the search's choice that came with it), 50 m drift median [worst] of 3
    noise copies: the simulated campus 1.5-6.3 [2.3-10.1] -> 0.9-1.6 [0.9-1.6] %; the
    de-skew grid's office (one run each) up to 9.3 -> 0.9 % (ust10lx), 3.3 -> 0.5 %
    (tim571); fr079 / MIT CSAIL / Intel (5 copies) 1.45 / 1.66 / 4.47 -> 1.04 / 1.20 /
    4.02 %, failed steps 16 (10 silent) -> 2 (2). In the hall, whose pillars are a
    few points each, 30 -> 41 failed steps of 10 800, announced but for 2 (3 before).
    """
    for j in range(points.shape[0] - 1):
        if not segment_ok[j]:
            continue
        a, b = fitted[j], fitted[j + 1]
        sign = 1.0 if a[0] * b[0] + a[1] * b[1] >= 0.0 else -1.0
        nx, ny = a[0] + sign * b[0], a[1] + sign * b[1]
        norm = math.hypot(nx, ny)
        if norm == 0.0:
            continue
        nx, ny = nx / norm, ny / norm
        if nx * table[j, 6] + ny * table[j, 7] < 0.0:  # the segment's own orientation
            nx, ny = -nx, -ny
        offset = 0.5 * (nx * (points[j, 0] + points[j + 1, 0])
                        + ny * (points[j, 1] + points[j + 1, 1]))
        table[j, 6], table[j, 7], table[j, 8] = nx, ny, offset
        table[j + 1, 3], table[j + 1, 4], table[j + 1, 5] = nx, ny, offset


@numba.njit(cache=True, nogil=True)
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
    normals = np.zeros((n, 2))
    if n < 3:
        return normals
    # Arc length along the scan; a break between runs counts as an unbridgeable jump.
    arc = np.zeros(n)
    for j in range(n - 1):
        arc[j + 1] = arc[j] + (length[j] if segment_ok[j] else 1e9)
    lo = np.searchsorted(arc, arc - 0.5 * window, side='left')
    hi = np.searchsorted(arc, arc + 0.5 * window, side='right')
    sums = np.zeros((n + 1, 5))
    for j in range(n):
        x, y = points[j, 0], points[j, 1]
        sums[j + 1, 0] = sums[j, 0] + x
        sums[j + 1, 1] = sums[j, 1] + y
        sums[j + 1, 2] = sums[j, 2] + x * x
        sums[j + 1, 3] = sums[j, 3] + x * y
        sums[j + 1, 4] = sums[j, 4] + y * y
    for j in range(n):
        count = hi[j] - lo[j]
        if count < 3:
            continue
        sx, sy = sums[hi[j], 0] - sums[lo[j], 0], sums[hi[j], 1] - sums[lo[j], 1]
        mean_x, mean_y = sx / count, sy / count
        cxx = (sums[hi[j], 2] - sums[lo[j], 2]) / count - mean_x * mean_x
        cxy = (sums[hi[j], 3] - sums[lo[j], 3]) / count - mean_x * mean_y
        cyy = (sums[hi[j], 4] - sums[lo[j], 4]) / count - mean_y * mean_y
        direction = 0.5 * math.atan2(2.0 * cxy, cxx - cyy)
        normals[j, 0], normals[j, 1] = -math.sin(direction), math.cos(direction)
    return normals


@dataclass
class Pairs:
    """Trimmed point-to-line pairs of one iteration.

    ``points`` are the paired current points moved by the estimate, ``normals`` and
    ``offset`` their lines ``n . x = n . q``; ``nearest`` is each pair's nearest
    reference point ``j1``.
    """

    points: np.ndarray
    normals: np.ndarray
    nearest: np.ndarray
    offset: np.ndarray


def pair_with_segments(segments: ReferenceSegments, index: BearingIndex, moved: np.ndarray,
                       max_distance: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pair moved current points with reference segments (Censi 2008, Sec. III).

    Each point's nearest reference point ``j1`` (within ``max_distance``) is found in
    the reference's bearing index; the segment goes to whichever of ``j1 - 1`` /
    ``j1 + 1`` is closer to the point, among those that form a segment with ``j1``.
    Returns the indices of the paired current points, their segment ids
    (``2 j1 + side``) and their lines ``(n_x, n_y, n . q)``.
    """
    moved = np.ascontiguousarray(moved, dtype=float).reshape(-1, 2)
    paired, segment_id, line = _pair(segments.table, index.sorted_points, index.bearings,
                                     index.directions, index.order, moved,
                                     float(max_distance),
                                     np.full(moved.shape[0], -1, dtype=np.int64))
    return paired, segment_id, line


@numba.njit(cache=True, nogil=True)
def _pair(table: np.ndarray, sorted_points: np.ndarray, bearings: np.ndarray,
          directions: np.ndarray, order: np.ndarray, moved: np.ndarray, max_distance: float,
          hints: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Compiled kernel of :func:`pair_with_segments` (``hints``: see nearest_by_bearing)."""
    _, nearest = nearest_by_bearing(sorted_points, bearings, directions, order, moved,
                                    max_distance, hints)
    count = moved.shape[0]
    paired = np.empty(count, dtype=np.int64)
    segment_id = np.empty(count, dtype=np.int64)
    line = np.empty((count, 3))
    k = 0
    for i in range(count):
        j = nearest[i]
        if table[j, 9] == 0.0:
            continue
        use_next = moved[i, 0] * table[j, 0] + moved[i, 1] * table[j, 1] < table[j, 2]
        first = 6 if use_next else 3
        paired[k] = i
        segment_id[k] = 2 * j + (1 if use_next else 0)
        line[k, 0] = table[j, first]
        line[k, 1] = table[j, first + 1]
        line[k, 2] = table[j, first + 2]
        k += 1
    return paired[:k], segment_id[:k], line[:k]


WEIGHT_STEPS = 256
"""Resolution of the Huber weights in a pairing's hash: a pairing whose weights still
change by more is not a repeat (the reweighted fit has not settled)."""


@numba.njit(cache=True, nogil=True)
def pair_and_trim(table: np.ndarray, sorted_points: np.ndarray, bearings: np.ndarray,
                  directions: np.ndarray, order: np.ndarray, points: np.ndarray,
                  estimate: np.ndarray, max_distance: float, keep_fraction: float,
                  min_keep_fraction: float, max_keep_fraction: float,
                  trim_sigma: float, huber_sigmas: float, hints: np.ndarray) -> tuple:
    """One PL-ICP pairing: move, pair, trim or weight, and sum the normal equations.

    ``points`` are moved by ``estimate`` and paired (:func:`pair_with_segments`).
    With ``huber_sigmas`` <= 0 the pairs with the smallest point-to-line residuals are
    kept - a fixed ``keep_fraction``, or when it is negative the adaptive fraction
    (:func:`adaptive_keep_fraction`) - each with weight one. With ``huber_sigmas`` > 0
    every pair is kept and weighted by the Huber kernel beyond that many robust sigmas
    (:func:`huber_weights`). ``hints`` carry each point's nearest reference
    point from one iteration to the next (:func:`.nearest.nearest_by_bearing`, updated
    in place). Returns the kept current-point indices, their
    moved points, lines ``(n_x, n_y, n . q)``, segment ids and weights, the normal
    equations ``M = sum w a a^T``, ``m = sum w (n . q) a`` of the closed-form step
    (``a = (n_x, n_y, n . p, n x p)``, :func:`.plicp.solver.solve_normal_equations`),
    and a hash of the pairing and its weights (to :data:`WEIGHT_STEPS`; equal pairings
    and weights give equal steps: a repeat is a cycle).
    """
    moved = move_points(estimate, points)
    paired, segment_id, line = _pair(table, sorted_points, bearings, directions, order,
                                     moved, max_distance, hints)
    count = paired.shape[0]
    residuals = np.empty(count)
    for k in range(count):
        i = paired[k]
        residuals[k] = line[k, 0] * moved[i, 0] + line[k, 1] * moved[i, 1] - line[k, 2]
    if huber_sigmas > 0.0:
        weights = huber_weights(residuals, huber_sigmas)
        kept = np.arange(count)
    else:
        if keep_fraction < 0.0:
            keep_fraction = adaptive_keep_fraction(residuals, min_keep_fraction,
                                                   max_keep_fraction, trim_sigma)
        kept = np.flatnonzero(trimmed_mask(residuals, keep_fraction))
        weights = np.ones(count)
    size = kept.shape[0]
    kept_paired = np.empty(size, dtype=np.int64)
    kept_moved = np.empty((size, 2))
    kept_line = np.empty((size, 3))
    kept_segment = np.empty(size, dtype=np.int64)
    kept_weight = np.empty(size)
    big_m = np.zeros((4, 4))
    small_m = np.zeros(4)
    signature = np.uint64(14695981039346656037)
    prime = np.uint64(1099511628211)
    for m in range(size):
        k = kept[m]
        i = paired[k]
        px, py = moved[i, 0], moved[i, 1]
        nx, ny, offset = line[k, 0], line[k, 1], line[k, 2]
        w = weights[k]
        kept_paired[m], kept_segment[m], kept_weight[m] = i, segment_id[k], w
        kept_moved[m, 0], kept_moved[m, 1] = px, py
        kept_line[m, 0], kept_line[m, 1], kept_line[m, 2] = nx, ny, offset
        a0, a1, a2, a3 = nx, ny, nx * px + ny * py, ny * px - nx * py
        small_m[0] += w * a0 * offset
        small_m[1] += w * a1 * offset
        small_m[2] += w * a2 * offset
        small_m[3] += w * a3 * offset
        big_m[0, 0] += w * a0 * a0
        big_m[0, 1] += w * a0 * a1
        big_m[0, 2] += w * a0 * a2
        big_m[0, 3] += w * a0 * a3
        big_m[1, 1] += w * a1 * a1
        big_m[1, 2] += w * a1 * a2
        big_m[1, 3] += w * a1 * a3
        big_m[2, 2] += w * a2 * a2
        big_m[2, 3] += w * a2 * a3
        big_m[3, 3] += w * a3 * a3
        signature = (signature ^ np.uint64(i)) * prime  # FNV-1a over the pairing
        signature = (signature ^ np.uint64(segment_id[k])) * prime
        signature = (signature ^ np.uint64(int(w * WEIGHT_STEPS))) * prime
    for a in range(4):
        for b in range(a):
            big_m[a, b] = big_m[b, a]
    return (kept_paired, kept_moved, kept_line, kept_segment, kept_weight, big_m, small_m,
            signature, count)


@numba.njit(cache=True, nogil=True)
def huber_weights(residuals: np.ndarray, sigmas: float) -> np.ndarray:
    """Return Huber IRLS weights: one within ``sigmas`` robust sigmas, falling beyond.

    The robust sigma (:func:`.robust.robust_sigma`) is floored at a micrometre, so a
    noise-free fit does not make every residual an outlier.
    """
    if residuals.shape[0] == 0:
        return np.ones(0)
    scale = sigmas * max(robust_sigma(residuals), 1e-6)
    return kernel_weights(residuals, HUBER, scale)
