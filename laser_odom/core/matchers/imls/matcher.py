"""IMLS-ICP: point-to-implicit-surface matching of informative points (2D IMLS-SLAM).

Deschaud, "IMLS-SLAM: scan-to-model matching based on 3D data", ICRA 2018, section
III, brought to 2D scan-to-scan odometry:

1. The reference scan is an implicit surface, Kolluri's IMLS function I(x) over its
   points and normals (eq. 1, :mod:`laser_odom.core.matchers.imls.surface`).
2. A few informative current points are chosen once per match (section III-B): the
   best ``points_per_list`` of each of four lists scoring x, y and +/- rotation
   observability, weighted by planarity.
3. Each iteration moves the selected points by the estimate, projects them onto the
   surface, ``y_j = x_j - I(x_j) n_j`` with ``n_j`` the normal of the nearest
   reference point (section III-C), and takes one Gauss-Newton step on the
   point-to-plane cost ``sum_j w_j (n_j . (R x_j + t - y_j))^2`` (eq. 2), ``w_j`` the
   squared planarity of the reference point.
4. The information matrix is the point-to-plane Hessian over *all* current points
   that have a surface value at the final estimate (outliers trimmed), not only the
   selected ones: the selection deliberately balances the directions, so its Hessian
   would hide the very degeneracy (a corridor) that the pipeline reads from the
   eigenvalues. Its normals come from wider neighbourhoods (``information_neighbours``)
   so that normal noise does not pose as information along a wall, and what noise
   they keep is removed from each term (errors in variables, as ``nicp`` does:
   :func:`.information.debiased_point_to_line_information`); in a featureless
   corridor the axis otherwise looked observed and the odometry ran away.
5. Scan-to-scan, the roles of the two scans are not symmetric: the surface comes
   from the reference, so its sparse sampling and noisy normals (far walls,
   one-degree beams) pass into the estimate. With ``symmetric`` the reference is also
   matched against the current scan's surface, from the inverse of the result, and
   the two estimates are fused by their information (the minimum of the sum of both
   costs, to second order; the idea of two-sided point-to-plane costs, cf.
   Rusinkiewicz, "A symmetric objective function for ICP", SIGGRAPH 2019).

What the paper leaves to the application (it matches to a model of many scans after
a good motion prior) is handled for scan-to-scan odometry with a constant-velocity
guess: when the guess overlaps the reference poorly, a heading search re-seeds it
(the guess misses most when the robot starts or stops turning); the iterations then
run in two stages, an *approach* (capture radius ``max_correspondence_distance`` if
the guess is off, aligned steps extrapolated as in Besl & McKay's accelerated ICP)
and a *refinement* at the fine ``radius`` on an inlier set fixed once (adaptive
trimming), with steps halved whenever they reverse, since the nearest-point normal
jumps as the nearest point changes and plain steps can cycle.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from laser_odom.core import se2
from laser_odom.core.matchers.base import MatcherConfig, MatchResult, ScanMatcher
from laser_odom.core.matchers.imls.solver import (
    advance, fuse_directions, inverted_information, refine, ROTATION_LEVER, surface_information)
from laser_odom.core.matchers.imls.surface import (
    candidate_ranking, implicit_surface, select_on_surface, surface_model, SurfaceModel,
    SurfaceSample)
from laser_odom.core.matchers.information import covariance_from_information
from laser_odom.core.matchers.registry import register
from laser_odom.core.matchers.robust import (
    kernel_code, KERNELS, median_magnitude)
from laser_odom.core.parameters import param, retune
from laser_odom.core.scan.laser_scan import ScanPoints
from laser_odom.core.scan.normals import estimate_normals, neighbourhoods, normal_variance

INFORMATION_MIN_NEIGHBOURS = 4
"""Points whose smoother normal rests on fewer neighbours add no information."""

COARSE_FRACTION = 0.25
"""The approach uses the capture radius when the median surface distance at the guess
exceeds this fraction of the fine radius."""

SEARCH_OVERLAP = 0.7
"""Heading search when fewer points than this fraction overlap the reference at the guess."""

SEARCH_STEP = 0.03
"""Heading step of the search [rad]."""

SEARCH_STRIDE = 3
"""The search probes every third point."""

COARSE_SHARE = 2.0 / 3.0
"""The approach ends after this share of ``max_iterations`` at the latest."""

ALIGNED_COSINE = 0.9
"""Coarse steps this well aligned with the previous one are extrapolated..."""

MAX_GAIN = 8.0
"""...doubling the step each time, up to this factor."""


IMLS_MAP_HEADING_WALK = 4e-7
"""imls' heading walk against the map [rad^2/m]: refined on the map's surfaces
(``map_surface_refine``) its heading holds better than the other matchers'. Whole-log
NEES on fr079 / MIT CSAIL / Intel (median of 5 copies with 1 mm range noise): with the
common 1e-5 0.4 / 1.2 / 1.3 (before the refinement), 3e-6 0.71 / 1.47 / 2.56, 1e-6
0.91 / 2.18 / 4.55, 5e-7 1.02 / 2.72 / 6.07, this value about 1.06 / 2.85 / 6.6, 0 1.38
on fr079 (its floor is the step covariance and the reference's own noise)."""


@dataclass
class ImlsConfig(MatcherConfig):
    """IMLS-ICP settings (defaults tuned on fr079, mit-csail and intel)."""

    max_iterations: int = param(
        20, 'Iteration cap of one match (Deschaud uses 20).', 1, 500)
    convergence_translation: float = retune(MatcherConfig, 'convergence_translation', 1e-4)
    convergence_rotation: float = retune(MatcherConfig, 'convergence_rotation', 1e-4)
    covariance_scale: float = retune(MatcherConfig, 'covariance_scale', 1.6)
    covariance_shared_scan: float = retune(MatcherConfig, 'covariance_shared_scan', 0.98)
    covariance_bias: float = retune(MatcherConfig, 'covariance_bias', 0.25)
    covariance_bias_correlation: float = retune(MatcherConfig, 'covariance_bias_correlation',
                                                0.999)
    map_surface_refine: bool = retune(MatcherConfig, 'map_surface_refine', True)
    map_covariance_heading_walk: float = retune(MatcherConfig, 'map_covariance_heading_walk',
                                                IMLS_MAP_HEADING_WALK)
    h: float = param(
        0.05, 'IMLS kernel width h [m]: W_i(x) = exp(-|x - p_i|^2 / h^2). Smaller keeps '
        'corners sharp (on a curve of radius R the surface is off by about h^2 / 4R).',
        0.001, 5.0)
    radius: float = param(
        0.3, 'Neighbourhood radius [m] of the IMLS sums; a point with no reference point '
        'this close has no surface value (clutter off the walls drops out).', 0.01, 10.0)
    max_neighbours: int = param(
        4, 'At most this many nearest reference points enter the IMLS sums.', 1, 100)
    min_neighbours: int = param(
        2, 'A point with fewer reference points within the radius has no surface '
        'value and is skipped.', 1, 100, at_most='max_neighbours')
    points_per_list: int = param(
        80, 'Informative points kept per observability list (x, y, +rotation, '
        '-rotation; IMLS-SLAM section III-B).', 1, 100000)
    planarity_power: float = param(
        2.0, 'Each residual is weighted by the planarity of its reference point to this '
        'power (0 = off): tangent lines at corners and on clutter are poorly defined.',
        0.0, 10.0)
    normal_neighbours: int = param(
        12, 'Neighbours (k nearest, the point included) of a normal estimate.', 3, 100)
    normal_radius: float = param(
        0.6, 'Neighbourhood radius [m] of a normal estimate.', 0.01, 10.0)
    normal_min_neighbours: int = param(
        2, 'Points with fewer neighbours within the radius have no normal; these nearest '
        'ones always count...', 2, 100, at_most='normal_neighbours')
    normal_extent: float = param(
        0.2, '...further ones only within this distance [m] (0 = off): on dense scans a '
        'fixed stretch of surface, on sparse ones the nearest few, not a span across '
        'corners.', 0.0, 10.0)
    information_neighbours: int = param(
        20, 'Neighbours of the smoother normals used for the information matrix (0: the '
        'matching normals). Noise in a normal adds n_x^2 ~ sigma^2 of spurious information '
        'along every wall, which would hide a corridor.', 0, 100)
    max_correspondence_distance: float = param(
        0.5, 'Capture radius [m]: after a poor guess the IMLS sums first reach this far '
        '(if beyond the radius), so points still find the surface.', 0.01, 10.0)
    search_angle: float = param(
        0.35, 'When the guess overlaps the reference poorly, headings up to this far '
        '[rad] from it are tried first (0 = off).', 0.0, 3.2)
    coarse_tolerance: float = param(
        0.01, 'The approach stage ends when a step moves less than this [m] and turns '
        'less than this [rad]; the inliers are then fixed and the estimate refined.',
        0.0, 1.0)
    outlier_sigmas: float = param(
        3.0, 'Points whose surface distance exceeds this many robust standard '
        'deviations (1.4826 MAD) are outliers...', 0.5, 100.0)
    min_keep_fraction: float = param(
        0.6, '...but at least this fraction of the points is kept.', 0.05, 1.0)
    projection_normal: str = param(
        'nearest', 'Normal of the projection y = x - I(x) n: nearest (that of the '
        'nearest reference point, as in IMLS-SLAM) or mean (kernel-weighted mean of the '
        'normals of the neighbours, ~ grad I).', choices=('nearest', 'mean'))
    robust_kernel: str = param(
        'none', 'Robust kernel on the point-to-plane residuals of the refinement.',
        choices=KERNELS)
    robust_scale: float = param(
        0.05, 'Scale [m] of the robust kernel.', 1e-4, 10.0)
    symmetric: bool = param(
        True, 'Also match the reference against the current scan and fuse both '
        'estimates: averages out the sampling and normal errors of a sparse reference.')


@register
class ImlsMatcher(ScanMatcher):
    """IMLS-ICP: informative current points against the reference's implicit surface."""

    name = 'imls'
    config_type = ImlsConfig
    config: ImlsConfig

    def _model(self, scan: ScanPoints) -> SurfaceModel:
        """Return the cached surface model of a scan under this configuration."""
        cfg = self.config
        # Both normal estimates (matching, information) share one neighbourhood search.
        neighbourhoods(scan, max(cfg.normal_neighbours, cfg.information_neighbours),
                       cfg.normal_radius)
        return surface_model(scan, cfg.normal_neighbours, cfg.normal_radius,
                             cfg.normal_min_neighbours,
                             cfg.normal_extent if cfg.normal_extent > 0.0 else None)

    def _surface(self, model: SurfaceModel, queries: np.ndarray,
                 radius: float | None = None) -> SurfaceSample:
        """Evaluate the reference surface at ``queries`` (default: the fine radius)."""
        cfg = self.config
        return implicit_surface(model, queries, cfg.h, cfg.radius if radius is None else radius,
                                cfg.max_neighbours, cfg.min_neighbours)

    def _rotation_search(self, reference: ScanPoints, points: np.ndarray,
                         guess: se2.Pose, search_angle: float) -> se2.Pose:
        """Re-seed the heading when the guess leaves most points off the reference.

        A constant-velocity guess misses the heading most when the robot starts or
        stops turning; ICP-type iterations do not recover a heading error of more than
        a few degrees. If fewer than ``SEARCH_OVERLAP`` of (every third of) the points
        lie within ``radius`` of a reference point, headings within ``search_angle``
        of the guess are tried and the one with the largest overlap is kept.
        """
        cfg = self.config
        probe = points[::SEARCH_STRIDE]
        index = reference.bearing_index

        def overlap(candidate: se2.Pose) -> float:
            distance, _ = index.nearest(se2.transform_points(candidate, probe), cfg.radius)
            return float(np.mean(np.isfinite(distance)))

        best, best_overlap = guess, overlap(guess)
        if best_overlap >= SEARCH_OVERLAP:
            return guess
        count = int(np.floor(search_angle / SEARCH_STEP))
        for offset in SEARCH_STEP * np.arange(-count, count + 1):
            candidate = advance(guess, np.array([0.0, 0.0, offset]))
            value = overlap(candidate)
            if value > best_overlap:
                best, best_overlap = candidate, value
        return best

    def match(self, reference: ScanPoints, current: ScanPoints,
              initial_guess: se2.Pose) -> MatchResult:
        """Align ``current`` to ``reference`` starting from ``initial_guess``.

        With ``symmetric`` the reference is then also matched against the current
        scan's surface, from the inverse of the forward result, and the two estimates
        are fused (:meth:`_symmetric`).
        """
        forward = self._match_directed(reference, current, initial_guess,
                                       self.config.search_angle)
        if not self.config.symmetric or not forward.converged:
            return forward
        backward = self._match_directed(current, reference, se2.inverse(forward.pose), 0.0)
        return self._symmetric(forward, backward)

    def _symmetric(self, forward: MatchResult, backward: MatchResult) -> MatchResult:
        """Fuse a forward match with the backward one (reference against current).

        Scan-to-scan IMLS is lopsided: the surface is built from one scan and sampled
        by the other, so where the reference is sparse (far walls, one-degree beams)
        its sampling and normal errors pass straight into the pose. Matching the other
        way round swaps the roles; the information-weighted mean of the two estimates
        (the minimum of the sum of both costs, to second order) averages those errors
        out. A backward match that failed, or that left the forward one by more than
        the surface ``radius`` (it lost the surface), is not used. The information is
        the mean of the two, not their sum: both directions rest on the same points.
        """
        if backward.converged:
            fused, difference = fuse_directions(forward.pose, forward.information,
                                                backward.pose, backward.information)
            apart = max(float(np.hypot(difference[0], difference[1])),
                        ROTATION_LEVER * abs(float(difference[2])))
            if apart <= self.config.radius:
                information = 0.5 * (forward.information + inverted_information(
                    backward.pose, backward.information))
                return replace(forward, pose=fused, information=information,
                               covariance=covariance_from_information(information),
                               iterations=forward.iterations + backward.iterations,
                               extra={**forward.extra, 'symmetric': True})
        return replace(forward, extra={**forward.extra, 'symmetric': False})

    def _match_directed(self, reference: ScanPoints, current: ScanPoints,
                        initial_guess: se2.Pose, search_angle: float) -> MatchResult:
        """Match ``current`` against the surface of ``reference`` (one direction)."""
        cfg = self.config
        estimate = np.array(initial_guess, dtype=float)
        if len(reference) < cfg.min_correspondences or len(current) < cfg.min_correspondences:
            return MatchResult.failure(estimate, reason='too few points')
        ref_model, cur_model = self._model(reference), self._model(current)
        ranking = candidate_ranking(cur_model)
        points = current.points
        # Selection (section III-B) among current points that reach the surface at the
        # initial guess, within the capture radius.
        capture = max(cfg.radius, cfg.max_correspondence_distance)
        if search_angle > 0.0:
            estimate = self._rotation_search(reference, points, estimate, search_angle)
        iterations = 0
        for attempt in range(2):
            start = estimate
            selected, sample = select_on_surface(
                ref_model, ranking, points, estimate, cfg.points_per_list, cfg.h, capture,
                cfg.max_neighbours, cfg.min_neighbours)
            if len(selected) < cfg.min_correspondences:
                return MatchResult.failure(estimate, iterations, len(selected),
                                           'too few points on the surface')
            estimate, converged, count = self._refine(
                ref_model, points[selected], sample, estimate, capture)
            iterations += count
            moved = se2.relative(start, estimate)
            if max(float(np.hypot(moved[0], moved[1])),
                   ROTATION_LEVER * abs(float(moved[2]))) <= cfg.radius:
                break
        return self._result(reference, current, ref_model, cur_model, estimate, converged,
                            iterations, len(selected))

    def _refine(self, ref_model: SurfaceModel, chosen: np.ndarray, sample: SurfaceSample,
                estimate: se2.Pose, capture: float) -> tuple[se2.Pose, bool, int]:
        """Iterate projection and Gauss-Newton steps; return (estimate, converged, count).

        ``sample`` is the surface at the ``chosen`` points under ``estimate`` within the
        ``capture`` radius. Two stages (:func:`.imls.solver.refine`): the approach,
        until a step moves less than ``coarse_tolerance``, then the refinement on a
        fixed inlier set. The approach reaches out to the capture radius only when the
        guess is off; after a good guess it keeps to the fine radius, where clutter a
        little off the walls has no surface value.
        """
        cfg = self.config
        far = median_magnitude(sample.value) > COARSE_FRACTION * cfg.radius
        index = ref_model.index
        estimate, converged, iterations = refine(
            index.sorted_points, index.bearings, index.directions, index.order,
            ref_model.normals, ref_model.usable, ref_model.offset, ref_model.curvature,
            np.ascontiguousarray(chosen, dtype=float), sample.value, sample.normal,
            sample.defined, sample.mean_normal, sample.nearest,
            np.asarray(estimate, dtype=float), far, capture, cfg.h, cfg.radius,
            cfg.max_neighbours, cfg.min_neighbours, cfg.max_iterations,
            cfg.min_correspondences, cfg.projection_normal == 'nearest',
            kernel_code(cfg.robust_kernel), cfg.robust_scale, cfg.planarity_power,
            cfg.coarse_tolerance, COARSE_SHARE, ALIGNED_COSINE, MAX_GAIN,
            cfg.min_keep_fraction, cfg.outlier_sigmas, cfg.convergence_translation,
            cfg.convergence_rotation)
        return estimate, bool(converged), int(iterations)

    def _result(self, reference: ScanPoints, current: ScanPoints, ref_model: SurfaceModel,
                cur_model: SurfaceModel, estimate: se2.Pose, converged: bool, iterations: int,
                selected: int) -> MatchResult:
        """Score the final estimate over all current points with a surface value."""
        cfg = self.config
        usable = cur_model.usable[:-1]
        moved = se2.transform_points(estimate, current.points)
        sample = self._surface(ref_model, moved)
        normals = sample.normal
        normal_var = np.zeros(len(current))
        if cfg.information_neighbours > 0:
            smooth = estimate_normals(reference, cfg.information_neighbours,
                                      cfg.normal_radius, INFORMATION_MIN_NEIGHBOURS)
            nearest = np.minimum(sample.nearest, len(reference) - 1)
            normals = smooth.normals[nearest]
            normal_var = normal_variance(smooth.covariance, smooth.count)[nearest]
            usable = usable & smooth.valid[nearest]
        ok = sample.defined & usable
        count = int(np.count_nonzero(ok))
        if count < cfg.min_correspondences:
            return MatchResult.failure(estimate, iterations, count,
                                       'too few points on the surface at the estimate')
        information, residual = surface_information(
            moved, estimate[:2], sample.value, np.ascontiguousarray(normals),
            np.ascontiguousarray(normal_var, dtype=float), ok,
            cfg.min_keep_fraction, cfg.outlier_sigmas, kernel_code(cfg.robust_kernel),
            cfg.robust_scale)
        return MatchResult(
            pose=estimate, converged=converged, iterations=iterations,
            inlier_ratio=count / len(current), residual=float(residual),
            information=information, covariance=covariance_from_information(information),
            correspondences=count, extra={'selected': selected})
