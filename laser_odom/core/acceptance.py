"""Judging a match before it is integrated: acceptance and degeneracy, for all matchers.

A match is accepted only if it converged, paired enough of the scan, and stayed close
to the prediction. Directions that the scene does not constrain (the axis of a
featureless corridor) are found from the eigen-decomposition of the match's
information matrix; along them the estimate keeps the prediction and a large variance
(in the spirit of Zhang, Kaess & Singh, "On degeneracy of optimization-based state
estimation problems", ICRA 2016).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from laser_odom.core import se2
from laser_odom.core.config import AcceptanceConfig
from laser_odom.core.matchers import MatchResult

DEGENERATE_VARIANCE = 1.0
"""Variance given to a degenerate direction [m^2 or rad^2]: as uncertain as the prior."""

REJECTED_VARIANCE = np.array([0.25, 0.25, 0.25])
"""Step variance of a rejected match (x, y, yaw)."""


@dataclass
class MatchVerdict:
    """What is integrated: the accepted (or substituted) pose, its covariance, a status."""

    pose: se2.Pose
    covariance: np.ndarray
    status: str


def rejection_reason(match: MatchResult, guess: se2.Pose,
                     config: AcceptanceConfig) -> str | None:
    """Return why a match is rejected, or None if it is acceptable."""
    if not match.converged:
        return 'not_converged'
    if not (se2.is_finite_pose(match.pose) and np.all(np.isfinite(match.covariance))):
        return 'non_finite'
    if match.inlier_ratio < config.min_inlier_ratio:
        return 'low_inlier_ratio'
    correction = se2.relative(guess, match.pose)
    if float(np.hypot(correction[0], correction[1])) > config.max_correction_linear:
        return 'large_correction'
    if abs(float(correction[2])) > config.max_correction_angular:
        return 'large_correction'
    return None


def metric_scale(length_scale: float) -> np.ndarray:
    """Return S = diag(1, 1, L): ``x = S x'`` maps ``[x, y, L theta]`` to ``[x, y, theta]``.

    Translation and rotation have different units; a rotation by theta moves points
    about ``L * theta`` metres, with L the typical range of the scan's points.
    """
    return np.array([1.0, 1.0, 1.0 / max(length_scale, 1e-3)])


def degenerate_directions(information: np.ndarray, length_scale: float,
                          min_information: float
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eigen-decompose the information in metric units; flag the weak directions.

    With ``H' = S H S`` (eigenvalues comparable, in 1/m^2), returns its eigenvalues,
    orthonormal eigenvectors, and which eigenvalues fall below ``min_information``.
    The threshold is absolute, not relative to the strongest direction: a long
    corridor with a few door frames is weak along its axis compared with across it,
    yet those features still pin the motion to a centimetre.
    """
    scale = metric_scale(length_scale)
    scaled = (information * scale[:, None]) * scale[None, :]
    values, vectors = np.linalg.eigh(0.5 * (scaled + scaled.T))
    weak = values < min_information
    return values, vectors, weak


def judge_match(match: MatchResult, guess: se2.Pose, config: AcceptanceConfig,
                length_scale: float = 1.0) -> MatchVerdict:
    """Accept, correct for degeneracy, or reject a match (then use the guess).

    ``length_scale`` [m] is the typical range of the scan's points, used to compare
    rotational with translational information.
    """
    reason = rejection_reason(match, guess, config)
    if reason is not None:
        match.extra['rejection'] = reason
        pose = guess if config.rejected_motion == 'predict' else se2.pose()
        return MatchVerdict(np.array(pose, dtype=float), np.diag(REJECTED_VARIANCE),
                            'rejected')
    values, vectors, weak = degenerate_directions(
        match.information, length_scale, config.degeneracy_min_information)
    if not np.any(weak):
        return MatchVerdict(match.pose.copy(), match.covariance.copy(), 'matched')
    match.degenerate = True
    scale = metric_scale(length_scale)
    correction = match.pose - guess
    correction[2] = se2.wrap_angle(correction[2])
    # Keep the correction only along the well-constrained directions (projection in
    # metric coordinates x' = S^-1 x, where the eigenvectors are orthonormal).
    strong = vectors[:, ~weak]
    pose = guess + scale * (strong @ (strong.T @ (correction / scale)))
    pose[2] = se2.wrap_angle(pose[2])
    variances = np.where(weak, DEGENERATE_VARIANCE, 1.0 / np.maximum(values, 1e-300))
    metric_covariance = (vectors * variances) @ vectors.T
    covariance = (metric_covariance * scale[:, None]) * scale[None, :]
    return MatchVerdict(pose, 0.5 * (covariance + covariance.T), 'degenerate')
