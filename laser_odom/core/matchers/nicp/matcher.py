"""NICP: normal-based ICP on extended points, solved by robust Gauss-Newton on SE(2).

Serafin & Grisetti, "NICP: Dense Normal Based Point Cloud Registration", IROS 2015,
for 2D scans. Each iteration pairs every current point with its nearest reference
point, drops pairs that fail the NICP rules (undefined normal, distance, normal angle,
curvature ratio), and takes one damped Gauss-Newton step (a fixed damping of the
diagonal, not an adaptive Levenberg-Marquardt lambda) on the 4-vector point-and-normal
error weighted by the reference point's information and a robust kernel (IRLS). The
error model is in :mod:`laser_odom.core.matchers.nicp.model`, the compiled iterations
in :mod:`laser_odom.core.matchers.nicp.solver`.
The information of the result is ``sum w J^T Omega J`` at the solution (with the point
information debiased for the noise of the normals and scaled by the a-posteriori
variance factor); when a direction of it is too weak (a featureless corridor's axis)
the result is flagged degenerate, with the test the pipeline's acceptance applies.
A match whose guess was poor is restarted from the rotation that aligns the normal
orientation histograms of the two scans.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from laser_odom.core import se2
from laser_odom.core.matchers.base import MatcherConfig, MatchResult, ScanMatcher
from laser_odom.core.matchers.information import covariance_from_information
from laser_odom.core.matchers.nicp.model import is_degenerate, normal_equations
from laser_odom.core.matchers.nicp.solver import FAILED_PAIRS, FAILED_SINGULAR, gauss_newton
from laser_odom.core.matchers.nicp.surface import (
    nicp_surface, NicpSurface, rotation_seed, SurfaceSettings)
from laser_odom.core.matchers.registry import register
from laser_odom.core.matchers.robust import kernel_code, KERNELS
from laser_odom.core.parameters import param, retune
from laser_odom.core.scan.laser_scan import ScanPoints

NICP_MAP_WEAK_SHARE = 0.05
"""nicp's ``map_surface_weak_share``. Refined on the map's cells in every direction, its
path along Intel's corridors shortened by 0.6 % (Intel copy 2, 50 m drift 0.44 -> 1.06 %):
the cells' few features there lag where the scans joined. Keeping the matcher's pose
where the cells measure less than this share of the pairs (5 copies with 1 mm range
noise, median [worst], ATE m / 50 m drift %, unrefined -> refined): fr079 0.44 [0.59] /
0.45 [0.50] -> 0.39 [0.54] / 0.36 [0.53], MIT CSAIL 0.95 [1.15] / 0.79 [0.99] -> 0.42 [0.45]
/ 0.53 [0.61], Intel 0.26 [0.47] / 0.56 [0.89] -> 0.19 [0.28] / 0.40 [0.66]. Over 10
copies 0.35 / 0.36, 0.43 / 0.56, 0.20 / 0.41 (medians); a share of 0.1 gave 0.31 / 0.45,
0.45 / 0.59, 0.20 / 0.46, and 0.2 (5 copies) 0.35 / 0.45, 0.54 / 0.63, 0.20 / 0.46."""

NICP_MAP_HEADING_WALK = 1e-6
"""nicp's heading walk against the map [rad^2/m], fitted once it was refined on the map's
surfaces: whole-log NEES on fr079 / MIT CSAIL / Intel (median of 5 copies with 1 mm
range noise) with the common 1e-5 0.6-1.0, 3e-6 1.2 / 0.9 / 1.4, 2e-6 1.3 / 1.0 / 1.6,
this value 1.4 / 1.1 / 1.8 (the walk no longer dominates: the step covariance and the
reference's own noise do)."""


@dataclass
class NicpConfig(MatcherConfig):
    """NICP settings; the defaults are tuned on the fr079, MIT-CSAIL and Intel logs."""

    covariance_shared_scan: float = retune(MatcherConfig, 'covariance_shared_scan', 0.95)
    covariance_bias: float = retune(MatcherConfig, 'covariance_bias', 0.4)
    covariance_bias_correlation: float = retune(MatcherConfig, 'covariance_bias_correlation',
                                                0.95)
    max_iterations: int = retune(MatcherConfig, 'max_iterations', 40)
    max_correspondence_distance: float = retune(MatcherConfig, 'max_correspondence_distance', 0.5)
    convergence_translation: float = retune(MatcherConfig, 'convergence_translation', 1e-4)
    convergence_rotation: float = retune(MatcherConfig, 'convergence_rotation', 1e-4)
    map_surface_refine: bool = retune(MatcherConfig, 'map_surface_refine', True)
    map_surface_weak_share: float = retune(MatcherConfig, 'map_surface_weak_share',
                                           NICP_MAP_WEAK_SHARE)
    map_covariance_heading_walk: float = retune(MatcherConfig, 'map_covariance_heading_walk',
                                                NICP_MAP_HEADING_WALK)
    convergence_chi2: float = param(
        0.01, '...or when the step changes e^T Omega e by less than this (a step '
        'along a direction the scene hardly constrains, such as a corridor axis).',
        0.0, 1e6)
    capture_distance: float = param(
        1.5, 'A match from a far guess (a search peak; not from a trusted prediction) '
        'first pairs points up to this far [m] apart, until it settles, then refines '
        'with max_correspondence_distance: along a corridor only the door '
        'frames and end walls tell the motion, and their partners lie a step away '
        '(no capture stage when not above max_correspondence_distance).', 0.0, 10.0)
    normal_neighbours: int = param(
        12, 'Neighbours (k nearest, the point included) of the normal estimate.', 2, 100)
    normal_radius: float = param(
        1.0, 'Normal neighbourhoods are limited to this radius [m].', 0.01, 10.0)
    normal_min_neighbours: int = param(
        3, 'A point with fewer neighbours than this has no normal.', 2, 100,
        at_most=('normal_neighbours', 'information_neighbours'))
    normal_extent: float = param(
        0.1, 'Neighbours beyond the normal_min_neighbours nearest count only within this '
        '[m] (dense scans: a fixed stretch of surface; sparse: the nearest few; 0 = off).',
        0.0, 10.0)
    information_neighbours: int = param(
        20, 'Neighbours of the wider normal estimate behind the information of the '
        'result (smoother normals claim less of a corridor axis).', 2, 100)
    information_radius: float = param(
        0.5, 'Radius [m] of the wider normal estimate behind the information.', 0.01, 10.0)
    max_curvature: float = param(
        0.3, 'Normals of points with a curvature above this are not defined (2D '
        'curvature is at most 0.5).', 0.0, 0.5)
    flat_curvature: float = param(
        0.1, 'Below this curvature the surface is flat and its normal is weighted by '
        'normal_information.', 0.0, 0.5, at_most='max_curvature')
    point_sigma: float = param(
        0.01, 'Range noise [m]: regularises the inverse neighbourhood covariance of the '
        'point information.', 1e-5, 1.0)
    tangent_sigma: float = param(
        3.0, 'Along a flat surface a point is this uncertain [m]: a wall sample does not '
        'tell where along the wall a point lies.', 0.0, 100.0)
    smooth_points: bool = param(
        True, 'Move each point on a flat surface onto the line fitted to its '
        'neighbourhood (removes most of the range noise from the point error).')
    normal_information: float = param(
        100.0, 'Information [1/rad^2] of the normal error on flat surfaces (1 elsewhere).',
        0.0, 1e6)
    max_normal_angle: float = param(
        0.3, 'Pairs whose normals differ by more than this [rad] are rejected.', 0.0,
        math.pi)
    max_curvature_ratio: float = param(
        1.5, 'Pairs with |log(curvature ratio)| above this are rejected.', 0.0, 100.0)
    curvature_floor: float = param(
        0.01, 'Curvatures below this count as this in the curvature ratio.', 1e-9, 0.5)
    robust_kernel: str = param(
        'huber', 'Robust kernel on the Mahalanobis error: none, huber, cauchy, tukey.',
        choices=KERNELS)
    robust_scale: float = param(
        3.0, 'Scale of the robust kernel, in Mahalanobis units.', 1e-6, 1e6)
    damping: float = param(
        1e-6, 'Damping of the Gauss-Newton step, relative to the diagonal of H (fixed, '
        'not an adaptive Levenberg-Marquardt lambda).', 0.0, 1e3)
    restart_inlier_ratio: float = param(
        0.5, 'A match that did not converge or paired fewer than this fraction of the '
        'points is restarted from the normal-histogram rotation.', 0.0, 1.0)
    restart_angle: float = param(
        0.1, 'A match is also run from the normal-histogram rotation when it differs '
        'from the guess by more than this [rad].', 0.0, math.pi)
    restart_window: float = param(
        0.6, 'The restart rotation is searched within this [rad] of the guess (0 = no '
        'restarts).', 0.0, math.pi)
    degeneracy_min_information: float = param(
        400.0, 'The result is degenerate when a direction of its information, rotation '
        "scaled by the scan's RMS range, is below this [1/m^2]: the pipeline "
        "acceptance's test and default (acceptance.degeneracy_min_information).",
        0.0, 1e12)
    covariance_scale: float = param(
        0.65, 'Factor on the match covariance (calibrated so that the normalised '
        'estimation error squared of the steps of simulated runs is about 3).',
        0.01, 1000.0)

    def surface_settings(self) -> SurfaceSettings:
        """Return the settings the per-scan surface depends on."""
        return SurfaceSettings(
            self.normal_neighbours, self.normal_radius, self.normal_min_neighbours,
            self.normal_extent, self.information_neighbours, self.information_radius,
            self.max_curvature, self.flat_curvature, self.point_sigma, self.tangent_sigma,
            self.normal_information, self.curvature_floor, self.smooth_points)


@dataclass
class Linearisation:
    """One linearisation of the NICP problem at a pose estimate.

    ``H`` and ``g`` of the normal equations, the pair count, the RMS point-to-surface
    distance [m] and the a-posteriori variance factor (weighted mean ``e^T Omega e``).
    """

    hessian: np.ndarray
    gradient: np.ndarray
    pairs: int
    residual: float
    variance_factor: float
    terms: tuple

    def reported_information(self, surface: NicpSurface) -> np.ndarray:
        """Return ``sum w J^T Omega J`` with the debiased point information, scaled.

        Divided by the variance factor (floored at 1: residuals larger than the
        assumed noise lower the confidence, smaller ones never raise it). Debiased
        rows may be indefinite; a direction whose sum came out negative holds no
        information, so the result is projected onto the positive semi-definite cone.
        """
        rotated, rotated_normals, point_error, normal_error, ref_index, weights = self.terms
        hessian, _ = normal_equations(rotated, rotated_normals, point_error, normal_error,
                                      surface.info_report[ref_index],
                                      surface.info_normal[ref_index], weights)
        values, vectors = np.linalg.eigh(0.5 * (hessian + hessian.T))
        hessian = (vectors * np.maximum(values, 0.0)) @ vectors.T
        return hessian / max(self.variance_factor, 1.0)


@register
class NicpMatcher(ScanMatcher):
    """Normal-based ICP with information-weighted, robust Gauss-Newton steps."""

    name = 'nicp'
    config_type = NicpConfig
    config: NicpConfig

    def match(self, reference: ScanPoints, current: ScanPoints,
              initial_guess: se2.Pose) -> MatchResult:
        """Align ``current`` to ``reference`` starting from ``initial_guess``.

        When the match from the guess is poor (not converged, or fewer than
        ``restart_inlier_ratio`` of the points paired), or the rotation that aligns the
        normal orientation histograms differs from the guess by more than
        ``restart_angle``, the match is also run from that rotation (with the guessed
        translation) and the best-paired result is kept. The inlier ratio counts the
        points with a defined normal: only they can be paired. (A restart from zero
        translation used to be tried too: along a corridor zero motion pairs more of
        the walls than the true motion a metre on, so it won over a correct match -
        fr079 every 10th scan, 1.06 m reported as 0.01 m with a 1 mm-tight heading.)
        """
        return self._match(reference, current, initial_guess, capture=True)

    def match_from_prediction(self, reference: ScanPoints, current: ScanPoints,
                              prediction: se2.Pose) -> MatchResult:
        """Refine a trusted prediction: :meth:`match` without the capture stage.

        Its step is within the pair gate, and pairs up to ``capture_distance`` only
        pull it towards surfaces a step away (MIT CSAIL at full rate, wheel-odometry
        prior: ATE 0.64 m with the capture stage, 0.57 m without).
        """
        return self._match(reference, current, prediction, capture=False)

    def _match(self, reference: ScanPoints, current: ScanPoints, initial_guess: se2.Pose,
               capture: bool) -> MatchResult:
        """:meth:`match`, with or without the capture stage."""
        cfg = self.config
        guess = np.array(initial_guess, dtype=float)
        if len(reference) < cfg.min_correspondences or len(current) < cfg.min_correspondences:
            return MatchResult.failure(guess, reason='too few points')
        settings = cfg.surface_settings()
        ref = nicp_surface(reference, settings)
        cur = nicp_surface(current, settings)
        if cur.index.size < cfg.min_correspondences:
            return MatchResult.failure(guess, reason='too few normals')
        length = current.length_scale
        result = self._optimise(reference, ref, cur, guess, length, capture)
        if cfg.restart_window <= 0.0:
            return result
        theta = rotation_seed(ref, cur, float(guess[2]), cfg.restart_window)
        disagree = abs(se2.wrap_angle(theta - guess[2])) > cfg.restart_angle
        if self._good(result) and not disagree:
            return result
        candidate = self._optimise(reference, ref, cur,
                                   np.array([guess[0], guess[1], theta]), length, capture)
        candidate.extra['restarted'] = True
        return candidate if self._better(candidate, result) else result

    def _good(self, result: MatchResult) -> bool:
        """Tell whether a match needs no restart."""
        return result.converged and result.inlier_ratio >= self.config.restart_inlier_ratio

    @staticmethod
    def _better(candidate: MatchResult, incumbent: MatchResult) -> bool:
        """Prefer converged matches, then the larger paired fraction."""
        return ((candidate.converged, candidate.inlier_ratio)
                > (incumbent.converged, incumbent.inlier_ratio))

    def _optimise(self, reference: ScanPoints, ref: NicpSurface, cur: NicpSurface,
                  start: np.ndarray, length_scale: float, capture: bool) -> MatchResult:
        """Run the robust Gauss-Newton iterations from ``start``; return the result.

        The iterations are :func:`.nicp.solver.gauss_newton`, first (when ``capture``)
        with pairs up to ``capture_distance`` apart until they settle (when it is the
        larger gate), then
        with ``max_correspondence_distance`` from there. Nearest-neighbour pairs within
        a 0.5 m gate leave a step longer than the gate along a corridor to the side
        walls alone, which say nothing along it, and the match stays where it started
        (from zero, 68 % of the MIT CSAIL keyframe pairs 1.1 m apart failed; with the
        capture stage 17 %). The information of the result is ``sum w J^T Omega J`` at
        the last linearisation, with the point information debiased for the noise of
        the normals and divided by the a-posteriori variance factor (mean weighted
        ``e^T Omega e`` per pair).
        """
        cfg = self.config
        start = np.asarray(start, dtype=float)
        settled, iterations = start, 0
        if capture and cfg.capture_distance > cfg.max_correspondence_distance:
            status, estimate, _, iterations, _ = self._iterate(
                reference, ref, cur, start, cfg.capture_distance)
            if status == 0 and se2.is_finite_pose(estimate):
                settled = estimate
        status, estimate, converged, more, system = self._iterate(
            reference, ref, cur, settled, cfg.max_correspondence_distance)
        iterations += more
        pairs, hessian, gradient, residual, variance_factor = system[:5]
        if status == FAILED_PAIRS:
            return MatchResult.failure(start, iterations, 0, 'too few pairs')
        if status == FAILED_SINGULAR:
            return MatchResult.failure(start, iterations, pairs, 'singular system')
        information = Linearisation(hessian, gradient, pairs, residual, variance_factor,
                                    system[5:]).reported_information(ref)
        return MatchResult(
            pose=estimate, converged=bool(converged), iterations=int(iterations),
            inlier_ratio=pairs / cur.index.size, residual=float(residual),
            information=information, covariance=covariance_from_information(information),
            correspondences=int(pairs),
            degenerate=is_degenerate(information, length_scale,
                                     cfg.degeneracy_min_information))

    def _iterate(self, reference: ScanPoints, ref: NicpSurface, cur: NicpSurface,
                 start: np.ndarray, max_distance: float) -> tuple:
        """Run :func:`.nicp.solver.gauss_newton` from ``start``, pairs up to ``max_distance``."""
        cfg = self.config
        index = reference.bearing_index
        return gauss_newton(
            index.sorted_points, index.bearings, index.directions, index.order, ref.points,
            ref.normals, ref.log_curvature, ref.usable, ref.info_point, ref.info_normal,
            cur.points_usable, cur.normals_usable, cur.log_curvature_usable, start,
            cfg.max_iterations, cfg.min_correspondences, max_distance,
            math.cos(cfg.max_normal_angle), cfg.max_curvature_ratio,
            kernel_code(cfg.robust_kernel), cfg.robust_scale, cfg.damping,
            cfg.convergence_translation, cfg.convergence_rotation, cfg.convergence_chi2)
