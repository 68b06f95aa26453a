"""How uncertain a match really is, from the evidence it already has.

A matcher's covariance is the curvature of its cost at the solution (the inverse of
``sum J^T Omega J``): it says how sharply the cost rises for small moves, not whether a
pose a metre away fits as well. Along a corridor, the doors and niches give the cost
some curvature, yet the scan fits almost as well one door further on. The evidence
that says how far the fit stays good, and along which direction, is **the correlative
search's score surface** (Olson, "Real-time correlative scan matching", ICRA 2009,
Sec. IV-B): every pose of the window was scored. Read as a likelihood, the scores give
a distribution over the window whose second moment about the chosen pose is the
search's covariance (Olson's eqs. 16-18 take the moments of the scores as
probabilities). The score here is the mean likelihood of the points (0..1); a scan's
points err together (the same wall, the same clutter), so the score is worth ``n``
independent points: ``p(x) ~ exp(n (s(x) - s_best))``.

A match from a prediction, which no search scored around, keeps the matcher's
covariance. The same likelihood evaluated along the weakest direction of the
matcher's information (a fit profile) was measured as its evidence: scan to scan it
moved no step of fr079, MIT CSAIL or Intel (5 copies with 1 mm range noise, 3
matchers) while it doubled the time per scan; against the local map it flagged the
map's view weak in Intel's corridors and handed those steps to the previous scan,
which under-measured them (nicp: 50 m drift 0.55 -> 1.29 %, 4 silent failed steps).

The distribution is at least as wide as its grid (a unique, sharp peak still
spreads over a cell or two), so only the part beyond :data:`FLOOR_CELLS` cells in each
metric eigen-direction counts (:func:`excess`): a well-constrained match keeps the
matcher's covariance, a weakly constrained one grows along the direction the scan does
not see. Rotation is measured as the arc at the scan's RMS range, as in
:mod:`laser_odom.core.uncertainty.degeneracy`.
"""

from __future__ import annotations

import numpy as np

from laser_odom.core import se2
from laser_odom.core.uncertainty.degeneracy import metric_scale

FLOOR_CELLS = 2.0
"""A score distribution narrower than this many grid cells (standard deviation, in each
metric eigen-direction) is the grid's own width, not uncertainty of the match."""


def likelihood_weights(scores: np.ndarray, effective_points: float) -> np.ndarray:
    """Return ``exp(n (s - s_max))``: the scores read as relative probabilities."""
    scores = np.asarray(scores, dtype=float)
    if scores.size == 0:
        return scores
    return np.exp(effective_points * (scores - scores.max()))


def spread_about(poses: np.ndarray, weights: np.ndarray, centre: se2.Pose) -> np.ndarray:
    """Return the weighted second moment (3x3) of ``poses`` about ``centre``.

    About the chosen pose, not the mean: a second peak as likely as the first makes
    the covariance cover it whichever of the two was chosen. Angles are wrapped.
    """
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    weights = np.asarray(weights, dtype=float)
    if poses.size == 0 or not np.isfinite(weights).all() or weights.sum() <= 0.0:
        return np.zeros((3, 3))
    offset = poses - np.asarray(centre, dtype=float)
    offset[:, 2] = se2.wrap_angle(offset[:, 2])
    moment = (offset * weights[:, None]).T @ offset / weights.sum()
    return 0.5 * (moment + moment.T)


def excess(covariance: np.ndarray, floor: float, length_scale: float) -> np.ndarray:
    """Return the part of ``covariance`` beyond ``floor`` [m^2] in each metric direction.

    The covariance is taken to metric units (``[x, y, L theta]``), each eigenvalue is
    lowered by ``floor`` (none below zero) and the result taken back.
    """
    scale = 1.0 / metric_scale(length_scale)  # [x, y, theta] -> [x, y, L theta]
    metric = covariance * scale[:, None] * scale[None, :]
    values, vectors = np.linalg.eigh(0.5 * (metric + metric.T))
    metric = (vectors * np.maximum(values - floor, 0.0)) @ vectors.T
    out = metric / scale[:, None] / scale[None, :]
    return 0.5 * (out + out.T)


def surface_covariance(poses: np.ndarray, scores: np.ndarray, centre: se2.Pose,
                       effective_points: float, cell: float,
                       length_scale: float) -> np.ndarray:
    """Return how far a score surface spreads about ``centre``, beyond its grid.

    ``poses`` and ``scores`` are the scored poses (the top of the search's surface),
    ``cell`` [m] the grid's cell; the result is the :func:`excess` of their
    likelihood-weighted second moment over :data:`FLOOR_CELLS` cells.
    """
    moment = spread_about(poses, likelihood_weights(scores, effective_points), centre)
    return excess(moment, (FLOOR_CELLS * cell) ** 2, length_scale)
