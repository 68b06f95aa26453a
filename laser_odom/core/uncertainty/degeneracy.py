"""Which directions of a match's information are too weak to trust (degeneracy).

Shared by the matchers (NICP's degenerate flag) and the pipeline's acceptance test, so
that both judge a match alike; it sits below both and imports neither. Translation
and rotation are compared in metric units: a rotation by theta moves the scan's points
about ``L theta`` metres, with ``L`` their RMS range (Zhang, Kaess and Singh, "On
degeneracy of optimization-based state estimation problems", ICRA 2016, judge the
eigenvalues of the information in the same way).
"""

from __future__ import annotations

import numpy as np

UNMEASURED_VARIANCE = 1e6
"""Variance [m^2, and rad^2 scaled by the length] of a direction the scan did not measure."""


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


def measured_only(covariance: np.ndarray, information: np.ndarray, length_scale: float,
                  min_information: float) -> np.ndarray:
    """Return a match's covariance with no information left along its weak directions.

    What the scans alone say about the step: along a direction whose information is
    below ``min_information`` the match's pose is where the matcher stopped, not a
    measurement, so the variance there is :data:`UNMEASURED_VARIANCE` (added along
    the weak eigenvectors, mapped back from metric units: ``S v``).
    """
    _, vectors, weak = degenerate_directions(information, length_scale, min_information)
    out = np.array(covariance, dtype=float)
    if np.any(weak):
        blind = metric_scale(length_scale)[:, None] * vectors[:, weak]
        out = out + UNMEASURED_VARIANCE * (blind @ blind.T)
    return 0.5 * (out + out.T)
