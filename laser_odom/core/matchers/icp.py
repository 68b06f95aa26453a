"""Point-to-point ICP with the closed-form SVD alignment step.

Besl & McKay, "A method for registration of 3-D shapes", PAMI 1992, with each
iteration's rigid fit solved in closed form by Arun, Huang & Blostein, "Least-squares
fitting of two 3-D point sets", PAMI 1987: centre both sets, take the SVD of their
cross-covariance ``H = U S V^T``, ``R = V diag(1, det(V U^T)) U^T`` (the diagonal
fixes the reflection case), ``t = mu_q - R mu_p``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from laser_odom.core import se2
from laser_odom.core.matchers.base import MatcherConfig, MatchResult, ScanMatcher
from laser_odom.core.matchers.correspondences import nearest_neighbours
from laser_odom.core.matchers.information import (
    covariance_from_information, information_from_jacobians, point_to_point_jacobians,
    residual_variance)
from laser_odom.core.matchers.registry import register
from laser_odom.core.matchers.robust import adaptive_keep_fraction, trimmed_mask
from laser_odom.core.params import param
from laser_odom.core.scan import ScanPoints


def align_svd(source: np.ndarray, target: np.ndarray,
              weights: np.ndarray | None = None) -> se2.Pose:
    """Return the rigid pose minimising ``sum w_i |R s_i + t - q_i|^2`` (Arun et al.)."""
    w = np.ones(source.shape[0]) if weights is None else weights
    w_sum = float(w.sum())
    mu_s = w @ source / w_sum
    mu_t = w @ target / w_sum
    cross = (source - mu_s).T @ ((target - mu_t) * w[:, None])
    u, _, vt = np.linalg.svd(cross)
    reflection = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rot = vt.T @ np.diag([1.0, reflection]) @ u.T
    trans = mu_t - rot @ mu_s
    return np.array([trans[0], trans[1], np.arctan2(rot[1, 0], rot[0, 0])])


@dataclass
class IcpConfig(MatcherConfig):
    """Point-to-point ICP settings (defaults tuned on the benchmark datasets)."""

    min_keep_fraction: float = param(
        0.7, 'Trimming: always keep at least this fraction of the gated pairs.', 0.1, 1.0)
    max_keep_fraction: float = param(
        0.95, 'Trimming: keep at most this fraction of the gated pairs.', 0.1, 1.0)


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
        tree = reference.tree
        converged = False
        iterations = 0
        for iterations in range(1, cfg.max_iterations + 1):
            moved = se2.transform_points(estimate, current.points)
            pairs = nearest_neighbours(tree, moved, cfg.max_correspondence_distance)
            if len(pairs) < cfg.min_correspondences:
                return MatchResult.failure(estimate, iterations, len(pairs), 'too few pairs')
            keep = adaptive_keep_fraction(
                pairs.distance, cfg.min_keep_fraction, cfg.max_keep_fraction)
            pairs = pairs.subset(trimmed_mask(pairs.distance, keep))
            updated = align_svd(current.points[pairs.current], reference.points[pairs.reference])
            step = se2.relative(estimate, updated)
            estimate = updated
            if self.converged_step(step):
                converged = True
                break
        moved = se2.transform_points(estimate, current.points)
        pairs = nearest_neighbours(tree, moved, cfg.max_correspondence_distance)
        residuals = moved[pairs.current] - reference.points[pairs.reference]
        rotated = moved[pairs.current] - estimate[:2]
        variance = residual_variance(residuals)
        information = information_from_jacobians(
            point_to_point_jacobians(rotated), None, variance)
        return MatchResult(
            pose=estimate, converged=converged, iterations=iterations,
            inlier_ratio=len(pairs) / len(current),
            residual=float(np.sqrt(np.mean(np.sum(residuals ** 2, axis=1)))) if len(pairs)
            else float('inf'),
            information=information, covariance=covariance_from_information(information),
            correspondences=len(pairs))
