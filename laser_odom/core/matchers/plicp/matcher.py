"""Point-to-line ICP (PL-ICP) with the exact closed-form step of Censi.

Censi, "An ICP variant using a point-to-line metric", ICRA 2008. Each current point,
moved by the current estimate, is paired with the segment between its nearest
reference point ``j1`` (one bounded search in the bearing index) and the closer of ``j1``'s
neighbours in beam order (Sec. III, step 2); pairs across a range discontinuity or a
gap of dropped beams are not segments. The error is the distance from the point to
the line through that segment, ``n^T (R p + t - q)``, and each iteration minimises the
sum of its squares exactly (Sec. IV and appendix; :mod:`.plicp.solver`).

Around that core: a coarse phase (wide gate, fixed keep fraction) brings a rough
prediction to the optimum, then a fine phase (tight gate, adaptive trimming of the
worst residuals) keeps moving people and unmatched scan edges out of the fit; the
iteration stops on a small step, a repeated pairing (a cycle, as CSM detects it) or
the cap. Against a view of the local map the fine phase first lets every pair pull
(Huber weights) and trims only from where that settles: trimming from the start is
blind to a corridor's axis, whose few witnesses it drops (``map_huber_sigma``). A
poor result is retried from the rotations where the two scans' wall directions
agree. The information matrix is the point-to-line Hessian with surface
normals fitted over a metre of wall, scaled by the residual variance.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from laser_odom.core import se2
from laser_odom.core.matchers.base import MatcherConfig, MatchResult, ScanMatcher
from laser_odom.core.matchers.histograms import wrapped
from laser_odom.core.matchers.information import (
    covariance_from_information, point_to_line_information)
from laser_odom.core.matchers.plicp.segments import (
    pair_with_segments, Pairs, reference_segments, ReferenceSegments)
from laser_odom.core.matchers.plicp.solver import iterate
from laser_odom.core.matchers.registry import register
from laser_odom.core.parameters import param, retune
from laser_odom.core.scan.laser_scan import ScanPoints
from laser_odom.core.scan.nearest import BearingIndex
from laser_odom.core.scan.normals import estimate_normals

PLICP_MAP_HEADING_WALK = 4e-6
"""plicp's heading walk against the map [rad^2/m]. Whole-log NEES on fr079 / MIT CSAIL /
Intel (median of 5 copies with 1 mm range noise): with the common 1e-5 0.73 / 2.52 /
3.24 (fr079 too pessimistic); with the surprise check (``map_surprised``), 4e-6 0.93 /
2.54 / 7.03 and 3e-6 1.04 / 2.73 / 8.66; refined on the map's surfaces
(``map_surface_refine``), 4e-6 0.6 / 1.6 / 4.6 (10 copies on fr079 and Intel) and 1.5e-6
0.8 / 2.4 / 8.1: no one value puts both fr079 and Intel within 1-8, and a filter is better
served by the pessimistic side."""

PLICP_MAP_RESTART_RESIDUAL = 0.02
"""plicp's ``map_restart_residual`` [m]. Restarts spend about half of its solver's
iterations against the map (fr079: 943 restarted matches of 4790, about a quarter of the
time per scan) and change the match rarely (0-11 times per Intel copy), but each change
steers the rest of the run.
Measured against the map (10 copies with 1 mm range noise and the copy as received; ATE
m / 50 m drift %, median [worst] over fr079, Intel, MIT CSAIL), no variant was better on
every log:

- this value: 0.095 [0.357] / 0.257 [0.391], 0.226 [0.718] / 0.595 [1.433] (3 failed
  steps, announced), 0.227 [0.383] / 0.430 [0.585]; as received, MIT CSAIL 0.21 / 0.43;
  the simulated campus and hall (seeds 1-3, 3 copies each): 4 failed steps (1 silent);
- 0 (never): 0.098 [0.143] / 0.266 [0.296], 0.155 [0.279] / 0.468 [0.654], 0.251
  [0.613] / 0.447 [0.717] with a failed step on MIT CSAIL (a corridor slide a restart
  left); as received, MIT CSAIL 0.46 / 0.56; fr079 every 5th scan at 10 Hz, a failed
  step more; simulated: 8 failed (4 silent);
- restarting only an unconverged run: as never on Intel and MIT CSAIL, fr079 alike (as
  received 0.20 / 0.29 against 0.09 / 0.26);
- keeping a converged first run when the best restart stops within 0.1 m and 3 deg of
  it: 0.090 [0.145] / 0.258 [0.309] with a failed step on fr079 (copy 1, scan 4509),
  0.142 [0.509] / 0.446 [0.929], 0.258 [0.517] / 0.449 [0.536]; as received, MIT CSAIL
  0.46 / 0.56; simulated: 6 failed (2 silent).

Intel gains from fewer restarts what MIT CSAIL and fr079 lose to a slide or a wrong view
(2026-12-07)."""

PLICP_MAX_SEGMENT_LENGTH = 0.5
"""plicp's ``max_segment_length`` [m]. Shorter segments make plicp hold in the simulated
hall of sparse pillars (issue 38's gap) but cost the real logs scan to scan. Measured
2026-12-07, the hall (3 seeds, slow and fast, 3 copies with 1 mm range noise; failed
steps summed (silent), 50 m drift median [worst] %) and the real logs (5 copies; 50 m
drift median [worst] %, failed (silent)):

- 0.5 (this value): hall scan to scan 59 (0), 6.6 [23.7]; against the map 4 (1), 0.26
  [2.2]; fr079 scan 1.04 [1.05], map 0.26 [0.39]; Intel scan 4.02 [4.04], map 0.77
  [1.43], 2 (0); MIT CSAIL scan 1.21 [1.22], map 0.44 [0.59];
- 0.35: hall 26 (0), 3.9 [11.8]; map 10 (1); fr079 scan 1.12, map 0.28 [1.53] with a
  silent failed step (ATE 2.39 m); Intel scan 4.26, map 0.43 [1.07], 1 (1); MIT CSAIL
  scan 1.16, map 0.47;
- 0.3: hall 14 (0), 3.0 [8.7]; map 3 (0), 0.18 [2.7];
- 0.25: hall 12 (1), 2.4 [7.4]; map 0 (0), 0.11 [1.2]; fr079 scan 1.15, map 0.33
  [0.44]; Intel scan 4.98 with 3 (2) failed, map 0.46 [1.23]; MIT CSAIL scan 1.27, map
  0.43 [0.70] with a silent failed step.

It is not the segments across small range jumps near the sensor: a segment no longer
than 4 or 6 times the beams' spacing at its nearer range left the hall as it was (54
failed scan to scan). Nor dropped beams: ``max_beam_gap`` 1 or 2 changed nothing."""

PLICP_SHARED_SCAN, PLICP_BIAS, PLICP_BASELINE_FALLOFF = 0.8, 0.05, 0.5
"""plicp's step-error shares (:mod:`laser_odom.core.uncertainty.pose_uncertainty`), fitted
since its segment lines take their surface's direction (``segment_window``). Simulated
office and cluttered worlds, 4 seeds each, 1 cm range noise, mean NEES over 1 / 10 / 100
steps and the whole run: office 2.5 / 2.9 / 2.7 / 1.7, cluttered 2.0 / 3.0 / 5.3 / 4.9;
with keyframes (0.3 m, 0.3 rad) the whole run 1.9 / 4.8. The shares of two-point lines
(0.6, 0.125, falloff 1) gave office 2.5 / 1.2 / 0.66 / 0.39 and cluttered 2.0 / 1.2 / 1.3
/ 1.1: a fitted line errs less alike from one step to the next, so more of a step's
error is the scans' own noise, which telescopes. A line fitted over 0.2 m is partly a
surface model, whose error does not fade with the baseline as a two-point line's does
(falloff 1: keyframes 3.8 / 9.7). On the real logs scan to scan the whole-log NEES goes
2.15 / 0.96 / 8.0 -> 2.45 / 1.03 / 9.60 (fr079 / MIT CSAIL / Intel, median of 5 copies;
Intel's plicp drifts 4 % scan to scan, more than its heading walk covers)."""


@dataclass
class PlicpConfig(MatcherConfig):
    """PL-ICP settings; the defaults are tuned on the benchmark logs (fr079, MIT, Intel)."""

    max_iterations: int = param(
        50, 'Iteration cap of one match (and of each restart).', 1, 500)
    max_correspondence_distance: float = param(
        0.15, 'Once the estimate settles, a current point farther than this [m] from '
        'every reference point is not paired.', 0.01, 10.0)
    convergence_translation: float = retune(MatcherConfig, 'convergence_translation', 1e-4)
    convergence_rotation: float = retune(MatcherConfig, 'convergence_rotation', 1e-4)
    covariance_scale: float = retune(MatcherConfig, 'covariance_scale', 2.0)
    covariance_shared_scan: float = retune(MatcherConfig, 'covariance_shared_scan',
                                           PLICP_SHARED_SCAN)
    covariance_bias: float = retune(MatcherConfig, 'covariance_bias', PLICP_BIAS)
    covariance_bias_correlation: float = retune(MatcherConfig, 'covariance_bias_correlation',
                                                0.98)
    covariance_baseline_falloff: float = retune(MatcherConfig, 'covariance_baseline_falloff',
                                                PLICP_BASELINE_FALLOFF)
    map_covariance_scale: float = retune(MatcherConfig, 'map_covariance_scale', 1.5)
    map_surface_refine: bool = retune(MatcherConfig, 'map_surface_refine', True)
    map_covariance_heading_walk: float = retune(MatcherConfig, 'map_covariance_heading_walk',
                                                PLICP_MAP_HEADING_WALK)
    max_beam_gap: int = param(
        3, 'Reference points whose beam indices differ by more than this do not form '
        'a segment.', 1, 1000)
    max_segment_length: float = param(
        PLICP_MAX_SEGMENT_LENGTH, 'Reference neighbours farther apart than this [m] are a range '
        'discontinuity, not a segment.', 0.01, 10.0)
    min_keep_fraction: float = param(
        0.9, 'Trimming: always keep at least this fraction of the paired points.',
        0.1, 1.0, at_most='max_keep_fraction')
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
        0.012, 'A match that did not converge or whose RMS residual exceeds this [m] is '
        'retried from the rotations where the surface directions of the two scans '
        'agree (0 = never).', 0.0, 10.0)
    map_restart_residual: float = param(
        PLICP_MAP_RESTART_RESIDUAL,
        'restart_residual against a view of the local map (reference: local_map): '
        'its lines are averages of many scans ray-cast across map cells, and even correct '
        'matches leave larger residuals on them (0 = never).', 0.0, 10.0)
    map_huber_sigma: float = param(
        3.5, 'Against a view of the local map (reference: local_map) the fine phase first '
        'weights every pair (Huber, beyond this many robust sigmas, 1.4826 MAD) and trims '
        'only once that fit settled: along a corridor the few pairs that see its axis '
        '(door frames, the far end) have the largest residuals while the estimate is off '
        'along it, and trimming from the start drops exactly them, so the match stays '
        'where it began. Just above trim_sigma: the weighted fit counts in full every '
        'pair the trimming may keep (0 = trim from the start, as against a scan).',
        0.0, 100.0)
    restart_max_rotation: float = param(
        0.4, 'Restart rotations are searched this far [rad] around the guess.',
        0.0, math.pi / 2)
    restart_candidates: int = param(
        4, 'Number of restart rotations tried.', 0, 20)
    segment_window: float = param(
        0.2, 'Length of surface [m] whose fitted direction each segment line of a real '
        'reference scan takes (0: the direction between its two points, as Censi).',
        0.0, 10.0)
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
    weights: np.ndarray
    """Each kept pair's weight in the fit: one once trimmed (Huber's if the iteration
    cap came first)."""

    @property
    def rms(self) -> float:
        """Weighted RMS point-to-line residual of the kept pairs at the final estimate [m]."""
        return float(np.sqrt(np.sum(self.weights * self.residuals ** 2)
                             / max(np.sum(self.weights), 1e-300)))


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
                                      cfg.information_window, cfg.segment_window)
        huber = cfg.map_huber_sigma if reference.virtual else 0.0
        run = self._run(segments, reference.bearing_index, current, guess, huber)
        iterations = run.iterations if run is not None else 0
        limit = cfg.map_restart_residual if reference.virtual else cfg.restart_residual
        if limit > 0.0 and (run is None or not run.converged or run.rms > limit):
            run, extra = self._restart(segments, reference, current, guess, run, limit,
                                       huber)
            iterations += extra
        if run is None:
            return MatchResult.failure(guess, iterations, 0, 'too few pairs')
        # Jacobians at the final estimate (rotated points R p = (R p + t) - t), with the
        # surface normals: the information the scene's geometry really holds.
        information = point_to_line_information(
            run.moved - run.estimate[:2], segments.surface_normals[run.pairs.nearest],
            run.residuals, run.weights)
        return MatchResult(
            pose=run.estimate, converged=run.converged, iterations=iterations,
            inlier_ratio=float(np.sum(run.weights)) / len(current), residual=run.rms,
            information=information, covariance=covariance_from_information(information),
            correspondences=len(run.residuals))

    def _restart(self, segments: ReferenceSegments, reference: ScanPoints,
                 current: ScanPoints, guess: se2.Pose, first: _Run | None,
                 limit: float, huber: float) -> tuple[_Run | None, int]:
        """Retry from the rotations where the wall directions agree; keep the best run.

        PL-ICP only converges near its guess, and a prediction can be tens of degrees
        off after a jerky turn (CSM restarts from perturbed guesses for the same
        reason). Runs are ranked by convergence, then by the fraction of current points
        within ``limit`` (the restart residual) of their line (a consensus, comparable
        between runs unlike a trimmed RMS). Returns the best run and the iterations spent.
        """
        cfg = self.config
        best = None if first is None else (
            first.converged, self._consensus(segments, reference, current, first, limit), first)
        iterations = 0
        for rotation in rotation_candidates(reference, current, guess[2],
                                            cfg.restart_max_rotation, cfg.restart_candidates):
            run = self._run(segments, reference.bearing_index, current,
                            np.array([guess[0], guess[1], rotation]), huber)
            if run is None:
                continue
            iterations += run.iterations
            if abs(se2.wrap_angle(run.estimate[2] - rotation)) > cfg.restart_max_rotation:
                continue  # drifted far from its seed: not a local refinement of it
            score = (run.converged, self._consensus(segments, reference, current, run, limit), run)
            if best is None or score[:2] > best[:2]:
                best = score
        return (None if best is None else best[2]), iterations

    def _run(self, segments: ReferenceSegments, index: BearingIndex, current: ScanPoints,
             guess: se2.Pose, huber: float = 0.0) -> _Run | None:
        """Iterate from ``guess`` until the step is small, a pairing repeats, or the cap.

        With ``huber`` > 0 the fine phase weights every pair (Huber, that many robust
        sigmas) until it settles, and trims only from there (``map_huber_sigma``).
        """
        cfg = self.config
        (found, estimate, converged, iterations, kept, moved, line, segment, weights,
         delta) = iterate(
            segments.table, index.sorted_points, index.bearings, index.directions,
            index.order, current.points, np.asarray(guess, dtype=float), cfg.max_iterations,
            cfg.min_correspondences, cfg.coarse_keep_fraction,
            cfg.coarse_correspondence_distance, cfg.coarse_step,
            cfg.max_correspondence_distance, cfg.min_keep_fraction, cfg.max_keep_fraction,
            cfg.trim_sigma, float(huber), cfg.convergence_translation,
            cfg.convergence_rotation)
        if not found:
            return None
        pairs = Pairs(moved, line[:, :2], segment >> 1, line[:, 2])
        # The kept pairs moved by the last step: their residuals at the final estimate.
        moved = se2.transform_points(delta, pairs.points)
        residuals = (pairs.normals[:, 0] * moved[:, 0] + pairs.normals[:, 1] * moved[:, 1]
                     - pairs.offset)
        return _Run(estimate, bool(converged), int(iterations), pairs, moved, residuals,
                    weights)

    def _consensus(self, segments: ReferenceSegments, reference: ScanPoints,
                   current: ScanPoints, run: _Run, limit: float) -> float:
        """Fraction of current points within ``limit`` of their reference line."""
        moved = se2.transform_points(run.estimate, current.points)
        index, _, line = pair_with_segments(segments, reference.bearing_index, moved,
                                            self.config.max_correspondence_distance)
        pts = moved[index]
        residuals = line[:, 0] * pts[:, 0] + line[:, 1] * pts[:, 1] - line[:, 2]
        return float(np.count_nonzero(np.abs(residuals) < limit)
                     / len(current))


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
    padded = wrapped(hist, 1)
    hist = 0.25 * (padded[:-2] + 2.0 * hist + padded[2:])
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
    padded = wrapped(correlation, 1)
    peak = ((correlation >= padded[:-2]) & (correlation > padded[2:])
            & (np.abs(offset) <= window) & (np.abs(offset) > 2.0 * width)
            & (correlation > 0.0))
    order = np.flatnonzero(peak)[np.argsort(-correlation[peak])]
    return [float(se2.wrap_angle(guess + offset[k])) for k in order[:count]]
