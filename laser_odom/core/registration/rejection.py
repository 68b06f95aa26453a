"""The rejection rules: why a match is not trusted, with the numbers behind it.

A match from a trusted prediction is rejected when it did not converge, is not finite,
paired less than ``min_inlier_ratio`` of the scan or lies more than
``max_correction_*`` from the prediction (:func:`rejection_reason`); a match found by
the global search is judged by its surface overlap and its window instead
(:func:`searched_rejection_reason`). The registrar checks a local match with these
rules before it decides to search (:mod:`laser_odom.core.registration.registrar`), and
the acceptance judges the chosen match with them
(:mod:`laser_odom.core.registration.acceptance`): both import them from here.
"""

from __future__ import annotations

import math

import numpy as np

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import AcceptanceConfig, PipelineConfig
from laser_odom.core.matchers import MatchResult
from laser_odom.core.search import SearchWindow


def correction_from(guess: se2.Pose, pose: se2.Pose) -> tuple[float, float]:
    """Return how far ``pose`` lies from ``guess``: distance [m] and |angle| [rad]."""
    correction = se2.relative(guess, pose)
    return float(np.hypot(correction[0], correction[1])), abs(float(correction[2]))


def _quality_reason(match: MatchResult, config: AcceptanceConfig,
                    inlier_ratio: float) -> str | None:
    """Return why a match is unusable whatever the prediction, or None."""
    if not match.converged:
        return 'not_converged'
    if not (se2.is_finite_pose(match.pose) and np.all(np.isfinite(match.covariance))):
        return 'non_finite'
    if inlier_ratio < config.min_inlier_ratio:
        return 'low_inlier_ratio'
    return None


def rejection_reason(match: MatchResult, guess: se2.Pose,
                     config: AcceptanceConfig) -> str | None:
    """Return why a match from a trusted prediction is rejected, or None."""
    reason = _quality_reason(match, config, match.inlier_ratio)
    if reason is not None:
        return reason
    linear, angular = correction_from(guess, match.pose)
    if linear > config.max_correction_linear or angular > config.max_correction_angular:
        return 'large_correction'
    return None


def searched_rejection_reason(match: MatchResult, guess: se2.Pose,
                              config: AcceptanceConfig, window: SearchWindow) -> str | None:
    """Return why a match found by the global search is rejected, or None.

    The window (around the guess, axes of the reference frame) is the gate; the
    refinement may settle up to one search cell beyond its edge. The inlier ratio is
    the surface overlap measured by the search (the same for every matcher; a NICP
    pair also needs agreeing normals, which scans a metre apart often lack).
    """
    reason = _quality_reason(match, config, searched_inlier_ratio(match))
    if reason is not None:
        return 'low_overlap' if reason == 'low_inlier_ratio' else reason
    offset = np.asarray(match.pose, dtype=float) - guess
    slack = window.resolution
    if (max(abs(offset[0]), abs(offset[1])) > window.linear + slack
            or abs(float(se2.wrap_angle(offset[2]))) > window.angular + slack):
        return 'outside_window'
    return None


def searched_inlier_ratio(match: MatchResult) -> float:
    """Return the inlier ratio a searched match is judged by: its surface overlap."""
    return float(match.extra.get('surface_overlap', match.inlier_ratio))


def describe_rejection(reason: str, match: MatchResult, guess: se2.Pose,
                       config: PipelineConfig) -> str:
    """Return the reason with the numbers behind it, for the log."""
    acceptance = config.acceptance
    linear, angular = correction_from(guess, match.pose)
    if reason == 'not_converged':
        return f'not converged after {match.iterations} iterations'
    if reason == 'low_inlier_ratio':
        return (f'{match.inlier_ratio:.0%} of the points paired, min_inlier_ratio '
                f'{acceptance.min_inlier_ratio:.0%}')
    if reason == 'low_overlap':
        return (f'{searched_inlier_ratio(match):.0%} of the points on the reference '
                f'surface, min_inlier_ratio {acceptance.min_inlier_ratio:.0%}')
    if reason == 'large_correction':
        return (f'{linear:.2f} m / {math.degrees(angular):.1f} deg from the prediction, gate '
                f'{acceptance.max_correction_linear:.2f} m / '
                f'{math.degrees(acceptance.max_correction_angular):.1f} deg')
    if reason == 'outside_window':
        window = match.extra.get('window', config.search.window())
        return (f'{linear:.2f} m / {math.degrees(angular):.1f} deg from the prediction, '
                f'outside the search window +-{window.linear:.2f} m / '
                f'+-{math.degrees(window.angular):.1f} deg')
    return reason.replace('_', ' ')
