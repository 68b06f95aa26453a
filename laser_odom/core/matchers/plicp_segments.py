"""PL-ICP's view of the reference scan: segments between beam-order neighbours.

Censi, "An ICP variant using a point-to-line metric", ICRA 2008, Sec. III: a current
point is paired with the segment between its nearest reference point ``j1`` and the
closer of ``j1``'s neighbours in the scan's beam order, and its error is the distance
to the line through that segment. Everything per reference scan is computed once and
cached in ``ScanPoints.cache`` (a scan is the current scan once and the reference
once), so an iteration costs one KD-tree query and one table lookup.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

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

    ``design`` rows are ``a_i = (n_x, n_y, n.p, n x p)`` and ``offset`` is ``n . q``
    (the cost of :func:`solve_design`); ``nearest`` is each pair's nearest reference
    point ``j1``; ``signature`` identifies the pairing.
    """

    points: np.ndarray
    normals: np.ndarray
    nearest: np.ndarray
    design: np.ndarray
    offset: np.ndarray
    signature: int

    def __len__(self) -> int:
        """Return the number of pairs."""
        return int(self.points.shape[0])


def pair_with_segments(segments: ReferenceSegments, tree: cKDTree, moved: np.ndarray,
                       max_distance: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pair moved current points with reference segments (Censi 2008, Sec. III).

    One bounded KD-tree query finds each point's nearest reference point ``j1``; the
    segment goes to whichever of ``j1 - 1`` / ``j1 + 1`` is closer to the point,
    among those that form a segment with ``j1``. Returns the indices of the paired
    current points, their segment ids (``2 j1 + side``) and their table rows.
    """
    distance, nearest = tree.query(moved, k=1, distance_upper_bound=max_distance)
    rows = segments.table[nearest]
    index = np.flatnonzero(rows[:, 9])
    rows = rows[index]
    pts = moved[index]
    use_next = pts[:, 0] * rows[:, 0] + pts[:, 1] * rows[:, 1] < rows[:, 2]
    segment_id = 2 * nearest[index] + use_next
    return index, segment_id, np.where(use_next[:, None], rows[:, 6:9], rows[:, 3:6])
