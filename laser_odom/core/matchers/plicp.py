"""Point-to-line ICP (PL-ICP) with the exact closed-form step of Censi.

Censi, "An ICP variant using a point-to-line metric", ICRA 2008. Each current point,
moved by the current estimate, is paired with the segment between its nearest
reference point ``j1`` and the closer of ``j1``'s neighbours in beam order (Sec. III,
step 2); the error is the distance from the point to the line through that segment,
``n^T (R p + t - q)``. Each iteration minimises the sum of squared point-to-line
errors exactly (Sec. IV and the appendix): with ``x = (t_x, t_y, cos, sin)`` the cost
is a quadratic ``x^T M x - 2 m^T x`` under the constraint ``x3^2 + x4^2 = 1``, whose
Lagrange multiplier is the largest real root of a fourth-degree polynomial (CSM's
``gpc_solve``). Outliers are gated by distance and trimmed by their residuals.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from laser_odom.core import se2
from laser_odom.core.matchers.base import MatcherConfig, MatchResult, ScanMatcher
from laser_odom.core.matchers.information import (
    covariance_from_information, information_from_jacobians, point_to_line_jacobians,
    residual_variance)
from laser_odom.core.matchers.plicp_solver import solve_design
from laser_odom.core.matchers.registry import register
from laser_odom.core.matchers.robust import adaptive_keep_fraction, trimmed_mask
from laser_odom.core.normals import estimate_normals
from laser_odom.core.params import param
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


def pair_with_segments(segments: ReferenceSegments, tree, moved: np.ndarray,
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


@dataclass
class PlicpConfig(MatcherConfig):
    """PL-ICP settings; the defaults are tuned on the benchmark logs (fr079, MIT, Intel)."""

    max_iterations: int = param(
        50, 'Iteration cap of one match (and of each restart).', 1, 500)
    max_correspondence_distance: float = param(
        0.15, 'Once the estimate settles, a current point farther than this [m] from '
        'every reference point is not paired.', 0.01, 10.0)
    convergence_translation: float = param(
        1e-4, 'Converged when an iteration moves the pose less than this [m]...', 0.0, 1.0)
    convergence_rotation: float = param(
        1e-4, '...and rotates it less than this [rad].', 0.0, 1.0)
    covariance_scale: float = param(
        2.0, 'Factor on the match covariance from the residuals (inflation calibrated so '
        'that the normalised estimation error squared on simulated runs is about 3).',
        0.01, 1000.0)
    max_beam_gap: int = param(
        3, 'Reference points whose beam indices differ by more than this do not form '
        'a segment.', 1, 1000)
    max_segment_length: float = param(
        0.5, 'Reference neighbours farther apart than this [m] are a range '
        'discontinuity, not a segment.', 0.01, 10.0)
    min_keep_fraction: float = param(
        0.9, 'Trimming: always keep at least this fraction of the paired points.',
        0.1, 1.0)
    max_keep_fraction: float = param(
        0.95, 'Trimming: keep at most this fraction of the paired points.', 0.1, 1.0)
    trim_sigma: float = param(
        3.0, 'Trimming: keep residuals within this many robust sigmas (1.4826 MAD), '
        'clipped to the fractions above.', 0.5, 100.0)
    coarse_keep_fraction: float = param(
        0.95, 'While an iteration still moves the pose by more than coarse_step (the '
        'coarse phase), keep this fixed fraction of the pairs: far from the optimum '
        'correct pairs have large residuals too (0 = no coarse phase).', 0.0, 1.0)
    coarse_correspondence_distance: float = param(
        0.5, 'Pairing distance [m] of the coarse phase, which has to reach the optimum '
        'from the prediction.', 0.01, 10.0)
    coarse_step: float = param(
        0.01, 'Step [m and rad] below which the coarse phase ends.', 0.0, 1.0)
    restart_residual: float = param(
        0.03, 'A match that did not converge or whose RMS residual exceeds this [m] is '
        'retried from the rotations where the surface directions of the two scans '
        'agree (0 = never).', 0.0, 10.0)
    restart_max_rotation: float = param(
        0.6, 'Restart rotations are searched this far [rad] around the guess.',
        0.0, math.pi / 2)
    restart_candidates: int = param(
        3, 'Number of restart rotations tried.', 0, 20)
    information_window: float = param(
        1.0, 'Length of surface [m] over which the normals used for the information '
        'matrix are fitted (a two-point segment normal is too noisy for it).', 0.01, 10.0)


@dataclass
class _Run:
    """One PL-ICP iteration sequence from one initial guess."""

    estimate: np.ndarray
    converged: bool
    iterations: int
    pairs: Pairs
    moved: np.ndarray
    residuals: np.ndarray

    @property
    def rms(self) -> float:
        """RMS point-to-line residual of the kept pairs at the final estimate [m]."""
        return float(np.sqrt(np.mean(self.residuals ** 2)))


@register
class PlicpMatcher(ScanMatcher):
    """PL-ICP: beam-order segment correspondences, trimming, exact closed-form step."""

    name = 'plicp'
    config_type = PlicpConfig
    config: PlicpConfig

    def match(self, reference: ScanPoints, current: ScanPoints,
              initial_guess: se2.Pose) -> MatchResult:
        """Align ``current`` to ``reference`` starting from ``initial_guess``."""
        cfg = self.config
        guess = np.array(initial_guess, dtype=float)
        if len(reference) < cfg.min_correspondences or len(current) < cfg.min_correspondences:
            return MatchResult.failure(guess, reason='too few points')
        segments = reference_segments(reference, cfg.max_beam_gap, cfg.max_segment_length,
                                      cfg.information_window)
        run = self._run(segments, reference.tree, current, guess)
        iterations = run.iterations if run is not None else 0
        if cfg.restart_residual > 0.0 and (run is None or not run.converged
                                           or run.rms > cfg.restart_residual):
            best = None if run is None else (self._consensus(segments, reference, current,
                                                             run), run)
            for rotation in rotation_candidates(reference, current, guess[2],
                                                cfg.restart_max_rotation,
                                                cfg.restart_candidates):
                other = self._run(segments, reference.tree, current,
                                  np.array([guess[0], guess[1], rotation]))
                if other is None:
                    continue
                iterations += other.iterations
                if abs(se2.wrap_angle(other.estimate[2] - rotation)) > cfg.restart_max_rotation:
                    continue  # drifted far from its seed: not a local refinement of it
                score = (self._consensus(segments, reference, current, other), other)
                if best is None or (score[1].converged, score[0]) > (best[1].converged,
                                                                     best[0]):
                    best = score
            run = None if best is None else best[1]
        if run is None:
            return MatchResult.failure(guess, iterations, 0, 'too few pairs')
        # Jacobians at the final estimate (rotated points R p = (R p + t) - t), with the
        # surface normals: the information the scene's geometry really holds.
        information = information_from_jacobians(
            point_to_line_jacobians(run.moved - run.estimate[:2],
                                    segments.surface_normals[run.pairs.nearest]),
            None, residual_variance(run.residuals))
        return MatchResult(
            pose=run.estimate, converged=run.converged, iterations=iterations,
            inlier_ratio=len(run.residuals) / len(current), residual=run.rms,
            information=information, covariance=covariance_from_information(information),
            correspondences=len(run.residuals))

    def _run(self, segments: ReferenceSegments, tree, current: ScanPoints,
             guess: se2.Pose) -> _Run | None:
        """Iterate from ``guess`` until the step is small, a pairing repeats, or the cap."""
        cfg = self.config
        estimate = guess.copy()
        seen: set[int] = set()
        coarse = cfg.coarse_keep_fraction > 0.0
        converged = False
        iterations = 0
        for iterations in range(1, cfg.max_iterations + 1):
            moved = se2.transform_points(estimate, current.points)
            pairs = self._pairs(segments, tree, moved, coarse)
            if pairs is None:
                return None
            delta = solve_design(pairs.design, pairs.offset)
            updated = se2.compose(delta, estimate)
            step = se2.relative(estimate, updated)
            estimate = updated
            if coarse:
                coarse = (math.hypot(step[0], step[1]) >= cfg.coarse_step
                          or abs(step[2]) >= cfg.coarse_step)
                continue
            # The exact step depends only on the pairing, so a pairing seen before
            # means the iteration has entered a cycle (CSM's loop detection): stop.
            if self.converged_step(step) or pairs.signature in seen:
                converged = True
                break
            seen.add(pairs.signature)
        # The kept pairs moved by the last step: their residuals at the final estimate.
        moved = se2.transform_points(delta, pairs.points)
        residuals = (pairs.normals[:, 0] * moved[:, 0] + pairs.normals[:, 1] * moved[:, 1]
                     - pairs.offset)
        return _Run(estimate, converged, iterations, pairs, moved, residuals)

    def _consensus(self, segments: ReferenceSegments, reference: ScanPoints,
                   current: ScanPoints, run: _Run) -> float:
        """Fraction of current points within ``restart_residual`` of their reference line."""
        moved = se2.transform_points(run.estimate, current.points)
        index, _, line = pair_with_segments(segments, reference.tree, moved,
                                            self.config.max_correspondence_distance)
        pts = moved[index]
        residuals = line[:, 0] * pts[:, 0] + line[:, 1] * pts[:, 1] - line[:, 2]
        return float(np.count_nonzero(np.abs(residuals) < self.config.restart_residual)
                     / len(current))

    def _pairs(self, segments: ReferenceSegments, tree, moved: np.ndarray,
               coarse: bool) -> Pairs | None:
        """Return the gated and trimmed point-to-line pairs of the moved current scan."""
        cfg = self.config
        gate = cfg.coarse_correspondence_distance if coarse else cfg.max_correspondence_distance
        index, segment_id, line = pair_with_segments(segments, tree, moved, gate)
        if index.shape[0] < cfg.min_correspondences:
            return None
        pts = moved[index]
        nx, ny = line[:, 0], line[:, 1]
        n_dot_p = nx * pts[:, 0] + ny * pts[:, 1]
        residuals = n_dot_p - line[:, 2]
        if coarse:
            keep = cfg.coarse_keep_fraction
        else:
            keep = adaptive_keep_fraction(residuals, cfg.min_keep_fraction,
                                          cfg.max_keep_fraction, cfg.trim_sigma)
        mask = trimmed_mask(residuals, keep)
        design = np.column_stack((nx, ny, n_dot_p, ny * pts[:, 0] - nx * pts[:, 1]))[mask]
        segment_id = segment_id[mask]
        signature = hash((index[mask].tobytes(), segment_id.tobytes()))
        return Pairs(pts[mask], line[mask, :2], segment_id >> 1, design, line[mask, 2],
                     signature)


DIRECTION_BINS = 180
"""Bins of the surface-direction histogram over [0, pi) (1 deg each)."""

FLAT_CURVATURE = 0.05
"""Points with a larger curvature (l1 / (l1 + l2)) have no reliable surface direction."""


def direction_histogram(scan: ScanPoints) -> np.ndarray:
    """Histogram of surface directions (normal angle mod pi), cached per scan.

    Each flat point votes with its range, roughly the length of surface its beam
    covers, so near clutter does not outvote distant walls. Smoothed by (1, 2, 1) / 4.
    """
    cached = scan.cache.get('plicp_directions')
    if cached is not None:
        return cached
    surface = estimate_normals(scan)
    angle = np.arctan2(surface.normals[:, 1], surface.normals[:, 0]) % np.pi
    bins = np.minimum((angle * (DIRECTION_BINS / np.pi)).astype(int), DIRECTION_BINS - 1)
    weight = scan.ranges * (surface.valid & (surface.curvature < FLAT_CURVATURE))
    hist = np.bincount(bins, weight, minlength=DIRECTION_BINS)
    hist = 0.25 * (np.roll(hist, 1) + 2.0 * hist + np.roll(hist, -1))
    scan.cache['plicp_directions'] = hist
    return hist


def rotation_candidates(reference: ScanPoints, current: ScanPoints, guess: float,
                        window: float, count: int) -> list[float]:
    """Rotations within ``window`` of ``guess`` where the scans' surface directions agree.

    The circular cross-correlation of the two direction histograms (Weiss, Wetzler
    and von Puttkamer, "Keeping track of position and orientation of moving indoor
    systems by correlation of range-finder scans", IROS 1994) peaks at rotations that
    bring the current walls parallel to the reference walls; its ``count`` highest
    local maxima (1 deg resolution, skipping those within 2 deg of the guess, which
    was already tried) seed PL-ICP again when the first run failed.
    """
    if count <= 0 or len(reference) < 3 or len(current) < 3:
        return []
    ref_hist, cur_hist = direction_histogram(reference), direction_histogram(current)
    correlation = np.fft.irfft(np.fft.rfft(ref_hist) * np.conj(np.fft.rfft(cur_hist)),
                               DIRECTION_BINS)
    width = np.pi / DIRECTION_BINS
    offset = (np.arange(DIRECTION_BINS) * width - guess + 0.5 * np.pi) % np.pi - 0.5 * np.pi
    peak = ((correlation >= np.roll(correlation, 1)) & (correlation > np.roll(correlation, -1))
            & (np.abs(offset) <= window) & (np.abs(offset) > 2.0 * width)
            & (correlation > 0.0))
    order = np.flatnonzero(peak)[np.argsort(-correlation[peak])]
    return [float(se2.wrap_angle(guess + offset[k])) for k in order[:count]]
