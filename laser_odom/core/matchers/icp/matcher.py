"""Point-to-point ICP with the closed-form SVD alignment step.

Besl & McKay, "A method for registration of 3-D shapes", PAMI 1992, with each
iteration's rigid fit solved in closed form by Arun, Huang & Blostein, "Least-squares
fitting of two 3-D point sets", PAMI 1987 (the compiled iterations are in
:mod:`laser_odom.core.matchers.icp.solver`) against the reference densified along its
surface; from a far guess, coarse to fine (beam samples first).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from laser_odom.core import se2
from laser_odom.core.matchers.base import MatcherConfig, MatchResult, ScanMatcher
from laser_odom.core.matchers.correspondences import nearest_neighbours
from laser_odom.core.matchers.icp.solver import iterate
from laser_odom.core.matchers.information import (
    covariance_from_information, point_to_line_information)
from laser_odom.core.matchers.registry import register
from laser_odom.core.matchers.robust import trimmed_mask
from laser_odom.core.parameters import param, retune
from laser_odom.core.scan.laser_scan import densify, ScanPoints
from laser_odom.core.scan.nearest import BearingIndex
from laser_odom.core.scan.normals import estimate_normals


INFORMATION_NEIGHBOURS = 20
"""Neighbours of the reference normals behind the information (:func:`surface_information`)."""

INFORMATION_RADIUS = 0.5
"""Their neighbourhood radius [m]."""

COARSE_TOLERANCE = 10.0
"""The beam-sample phase stops at 10x the convergence thresholds: its optimum is biased
by the beam sampling by more than that, and the dense phase refines it anyway."""


@dataclass
class IcpConfig(MatcherConfig):
    """Point-to-point ICP settings (defaults tuned on the benchmark datasets)."""

    max_iterations: int = param(
        40, 'Iteration cap of each phase (beam samples, then densified surface).', 1, 500)
    convergence_translation: float = retune(MatcherConfig, 'convergence_translation', 1e-4)
    convergence_rotation: float = retune(MatcherConfig, 'convergence_rotation', 1e-4)
    covariance_scale: float = retune(MatcherConfig, 'covariance_scale', 2.5)
    covariance_shared_scan: float = retune(MatcherConfig, 'covariance_shared_scan', 0.5)
    covariance_bias: float = retune(MatcherConfig, 'covariance_bias', 0.2)
    covariance_bias_correlation: float = retune(MatcherConfig, 'covariance_bias_correlation',
                                                0.98)
    covariance_baseline_falloff: float = retune(MatcherConfig, 'covariance_baseline_falloff',
                                                1.0)
    map_covariance_scale: float = retune(MatcherConfig, 'map_covariance_scale', 1.9)
    map_surprise_check: bool = retune(MatcherConfig, 'map_surprise_check', False)
    max_correspondence_distance: float = retune(MatcherConfig, 'max_correspondence_distance', 0.3)
    min_keep_fraction: float = param(
        0.8, 'Trimming: always keep at least this fraction of the gated pairs.', 0.1, 1.0,
        at_most='max_keep_fraction')
    max_keep_fraction: float = param(
        0.8, 'Trimming: keep at most this fraction of the gated pairs.', 0.1, 1.0)
    reference_spacing: float = param(
        0.01, 'Densify the reference scan along its surface to this point spacing [m] '
        '(0 = off), so point-to-point pairs are not biased by beam sampling.', 0.0, 1.0)
    max_densify_gap: float = param(
        0.3, 'Only interpolate between neighbouring beams closer than this [m] (a larger '
        'gap is a range discontinuity, not a surface).', 0.0, 10.0)


@register
class IcpMatcher(ScanMatcher):
    """Point-to-point ICP: nearest neighbours, gating, trimming, SVD step."""

    name = 'icp'
    config_type = IcpConfig
    config: IcpConfig

    def match(self, reference: ScanPoints, current: ScanPoints,
              initial_guess: se2.Pose) -> MatchResult:
        """Align ``current`` to ``reference`` starting from ``initial_guess``."""
        cfg = self.config
        estimate = np.array(initial_guess, dtype=float)
        if len(reference) < cfg.min_correspondences or len(current) < cfg.min_correspondences:
            return MatchResult.failure(estimate, reason='too few points')
        # Dense first: near a good guess the densified surface alone is unbiased. The
        # beam samples have an optimum of their own where the beams fall on the spots
        # they hit before - along a corridor, no motion at all - so from a good guess a
        # coarse phase drags the estimate back by up to a whole step. Only a guess the
        # dense phase cannot settle from (a far one) goes coarse to fine, from the guess.
        dense, dense_index = self._dense_reference(reference)
        estimate, iterations, converged = self._iterate(dense, dense_index, current,
                                                        initial_guess, 1.0)
        tree = dense_index
        if not converged:
            estimate, iterations, converged, tree = self._coarse_to_fine(
                reference, current, initial_guess, iterations)
        if estimate is None:
            return MatchResult.failure(initial_guess, iterations, reason='too few pairs')
        moved = se2.transform_points(estimate, current.points)
        pairs = nearest_neighbours(tree, moved, cfg.max_correspondence_distance)
        if len(pairs) < cfg.min_correspondences:
            return MatchResult.failure(initial_guess, iterations, len(pairs), 'too few pairs')
        information = surface_information(reference, moved, estimate, cfg)
        kept = np.sort(pairs.distance)[:int(np.ceil(cfg.max_keep_fraction * len(pairs)))]
        return MatchResult(
            pose=estimate, converged=converged, iterations=iterations,
            inlier_ratio=len(pairs) / len(current),
            residual=float(np.sqrt(np.mean(kept ** 2))) if kept.size else float('inf'),
            information=information, covariance=covariance_from_information(information),
            correspondences=len(pairs))

    def prepare_reference(self, scan: ScanPoints) -> None:
        """Densify ``scan`` and estimate the normals behind the information (once per keyframe)."""
        self._dense_reference(scan)
        estimate_normals(scan, INFORMATION_NEIGHBOURS, INFORMATION_RADIUS)

    def _coarse_to_fine(self, reference: ScanPoints, current: ScanPoints,
                        initial_guess: se2.Pose, iterations: int
                        ) -> tuple[se2.Pose | None, int, bool, BearingIndex]:
        """Beam samples from a far guess, then the densified surface near the optimum.

        The beam samples move the estimate quickly; the dense phase removes their
        sampling bias. ``max_iterations`` caps each phase; ``iterations`` are those
        already spent. Returns the estimate (None if pairs ran out), the iterations,
        whether it converged and the index of the last phase's target.
        """
        converged = False
        estimate = np.array(initial_guess, dtype=float)
        phases = ((lambda: (reference.points, reference.bearing_index), COARSE_TOLERANCE),
                  (lambda: self._dense_reference(reference), 1.0))
        for phase, tolerance in phases:
            target, tree = phase()
            estimate, used, converged = self._iterate(target, tree, current, estimate,
                                                      tolerance)
            iterations += used
            if estimate is None or not converged:
                break  # pairs ran out, or the coarse phase did not settle
        return estimate, iterations, converged, tree

    def _dense_reference(self, reference: ScanPoints) -> tuple[np.ndarray, BearingIndex]:
        """Return the densified reference and its index, built once per reference scan."""
        cfg = self.config
        key = ('icp_dense', cfg.reference_spacing, cfg.max_densify_gap)
        if key not in reference.cache:
            dense = densify(reference, cfg.reference_spacing, cfg.max_densify_gap)
            reference.cache[key] = (dense, BearingIndex(dense))
        return reference.cache[key]

    def _iterate(self, target: np.ndarray, index: BearingIndex, current: ScanPoints,
                 estimate: se2.Pose, tolerance: float) -> tuple[se2.Pose | None, int, bool]:
        """Run up to ``max_iterations`` ICP iterations against ``target``.

        Returns the estimate (None if pairs ran out), the iterations used and whether
        the step fell below the convergence thresholds (:func:`.icp.solver.iterate`).
        """
        cfg = self.config
        paired, estimate, iterations, converged = iterate(
            index.sorted_points, index.bearings, index.directions, index.order,
            np.ascontiguousarray(target, dtype=float), current.points,
            np.asarray(estimate, dtype=float), cfg.max_iterations, cfg.min_correspondences,
            cfg.max_correspondence_distance, cfg.min_keep_fraction, cfg.max_keep_fraction,
            tolerance * cfg.convergence_translation, tolerance * cfg.convergence_rotation,
            current.length_scale)
        return (estimate if paired else None), int(iterations), bool(converged)


def surface_information(reference: ScanPoints, moved: np.ndarray, estimate: se2.Pose,
                        cfg: IcpConfig) -> np.ndarray:
    """Information of the final estimate under the point-to-surface approximation.

    The point-to-point Hessian claims information along walls that the scene does not
    provide (a point can slide along a wall at almost no cost once pairs are
    re-chosen), so a corridor would look well constrained. Projecting each residual
    on the reference surface normal gives the information the geometry really holds
    (as in Censi, "An accurate closed-form estimate of ICP's covariance", ICRA 2007).
    """
    surface = estimate_normals(reference, INFORMATION_NEIGHBOURS, INFORMATION_RADIUS)
    pairs = nearest_neighbours(reference.bearing_index, moved, cfg.max_correspondence_distance)
    pairs = pairs.subset(surface.valid[pairs.reference])
    if len(pairs) < 3:
        return np.zeros((3, 3))
    normals = surface.normals[pairs.reference]
    offsets = moved[pairs.current] - reference.points[pairs.reference]
    residuals = np.einsum('nd,nd->n', normals, offsets)
    keep = trimmed_mask(residuals, cfg.max_keep_fraction)
    kept = residuals[keep]
    return point_to_line_information(moved[pairs.current][keep] - estimate[:2], normals[keep],
                                     kept, np.ones(len(kept)))
