"""Judging a match before it is integrated: acceptance, ambiguity and degeneracy.

A match from a trusted prediction is accepted only if it converged, paired enough of
the scan and stayed within ``max_correction_*`` of the prediction. A match found by
the global search is judged by its own evidence instead: the search window is its
gate, and two distinct poses that fit alike make it ambiguous - reported degenerate,
with a covariance that covers the alternatives. Directions that the scene does not
constrain (the axis of a featureless corridor) are found from the eigen-decomposition
of the match's information matrix; along them the estimate keeps the prediction and a
large variance (in the spirit of Zhang, Kaess & Singh, "On degeneracy of
optimization-based state estimation problems", ICRA 2016).

The rejection rules themselves, shared with the registrar, are in
:mod:`laser_odom.core.registration.rejection`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import AcceptanceConfig, PipelineConfig
from laser_odom.core.matchers import MatchResult
from laser_odom.core.motion.blind_prior import Prediction
from laser_odom.core.registration.registrar import Registration
from laser_odom.core.registration.rejection import rejection_reason, searched_rejection_reason
from laser_odom.core.search import SearchWindow
from laser_odom.core.uncertainty.degeneracy import (
    degenerate_directions, measured_only, metric_scale)


DEGENERATE_VARIANCE = 1.0
"""Variance given to a degenerate direction [m^2 or rad^2]: as uncertain as the prior."""


@dataclass
class MatchVerdict:
    """What is integrated: the accepted (or substituted) pose, its covariance, a status."""

    pose: se2.Pose
    covariance: np.ndarray
    status: str


def judge_match(registration: Registration, guess: se2.Pose, config: PipelineConfig,
                length_scale: float = 1.0) -> MatchVerdict:
    """Accept, correct for ambiguity and degeneracy, or reject a match (then use the guess).

    ``length_scale`` [m] is the typical range of the scan's points, used to compare
    rotational with translational information.
    """
    match = registration.match
    window = registration.window or config.search.window()
    if registration.searched:
        reason = searched_rejection_reason(match, guess, config.acceptance, window)
    else:
        reason = rejection_reason(match, guess, config.acceptance)
    prediction = registration.prediction
    trusted = prediction if prediction is not None and prediction.source == 'prior' else None
    if reason is not None:
        match.extra['rejection'] = reason
        match.extra['window'] = window
        if config.acceptance.rejected_motion == 'predict':
            # The step is the prediction, as uncertain as its measured error when it
            # was trusted and nothing spoke against it; else - untrusted, or its match
            # failed or was doubted and the search found nothing either - it is
            # anywhere in the window.
            covariance = (rejected_covariance(window)
                          if trusted is None or registration.searched
                          else trusted.covariance)
            return MatchVerdict(np.array(guess, dtype=float), covariance, 'rejected')
        return MatchVerdict(se2.pose(), rejected_covariance(window), 'rejected')
    # Along a direction the scene does not constrain the estimate keeps the prediction
    # - when there is one to trust. Otherwise the searched and refined pose is the best
    # estimate there is, and its covariance says how weak it is.
    anchor = guess if registration.trusted else match.pose
    if not registration.trusted and prediction is not None:
        # The last step's translation; its turn is not predicted (blind_prior).
        anchor = np.array([prediction.pose[0], prediction.pose[1], match.pose[2]])
    elif registration.trusted and registration.searched:
        # The match from the prediction failed or was doubted, and the search measured
        # the turn: as for the last step's translation above, the prediction stands in
        # for the translation only. Kept as the anchor, the predicted turn's correction,
        # projected on the constrained directions, moved the translation along a
        # direction that couples it with the turn: by metres after a large turn (fr079
        # every 10th scan 0.1 s apart, nicp, scan 394: the search found the step within
        # 9 cm, 112 deg from the predicted turn, and 5.4 m off was published), and by
        # 0.3 m after a 14 deg one (every 5th scan, scan 877).
        anchor = np.array([guess[0], guess[1], match.pose[2]])
    verdict = _degeneracy(match, anchor, config.acceptance, length_scale, prediction)
    verdict = _weakly_constrained(match, verdict, config.acceptance, length_scale)
    if registration.alternatives:
        match.extra['ambiguous'] = True
        verdict = MatchVerdict(verdict.pose, covering_covariance(
            verdict.pose, verdict.covariance, [pose for pose, _ in registration.alternatives]),
            'degenerate')
    if (verdict.status == 'degenerate' and trusted is not None and trusted.carried
            and registration.trusted):
        # The prediction repeats a step that was not well constrained, and the step
        # keeps it where the match is blind, or was picked nearest it among poses that
        # fit alike: it is no better known than that step, in any direction. Where
        # the scene repeats (a hall of pillars) a wrong prediction leads to an alias a
        # few centimetres and degrees off the truth across the blind direction too,
        # which the blind direction's variance alone does not cover (the simulated
        # fast hall, plicp: 1.4 m along the aisle after a 1.5 m alias, published with
        # 1 cm across it: NEES 144).
        verdict = MatchVerdict(verdict.pose,
                               covering_both(verdict.covariance, trusted.covariance),
                               'degenerate')
    if registration.searched and match.extra.get('surface_fit', 1.0) < \
            config.search.global_search_poor_fit:
        # Even the widened search found no pose that fits well: the scans cannot tell
        # where the motion went, though the best guess stands. It is anywhere in the
        # window - or, with a trusted prediction, the prediction or the match.
        match.extra['poor_fit'] = True
        cover = rejected_covariance(window) if trusted is None else covering_covariance(
            verdict.pose, trusted.covariance, [trusted.pose])
        verdict = MatchVerdict(verdict.pose, verdict.covariance + cover, 'degenerate')
    return verdict


def published_covariance(verdict: MatchVerdict, match: MatchResult) -> np.ndarray:
    """Return the covariance a judged step is published with: it covers the other basins.

    From starts a little off the prediction the matcher stopped elsewhere with as good
    a fit (:mod:`.basins`, the match's ``basins``): the pose stands, the covariance
    covers those poses (:func:`covering_covariance`) and compounds as the step's own
    does (:func:`.pose_uncertainty.step_error`: against the local map the map anchors
    a basin as it anchors the match). Only what is published grows: the tests that
    compare a step with another within their covariances (the local map's second
    opinions) keep the matcher's own. A step that was not well constrained carries it
    on as the velocity's error (``velocity_update: replace``); measured, no pose of
    the real logs or the fast logs changed.
    """
    basins = match.extra.get('basins')
    if not basins:
        return verdict.covariance
    return covering_covariance(verdict.pose, verdict.covariance, basins)


def measured_covariance(match: MatchResult, config: AcceptanceConfig,
                        length_scale: float) -> np.ndarray:
    """Return the covariance of what the scans alone say about a match's pose.

    The matcher's covariance and the search surface's spread where the search ran,
    with no information along the weak directions: none of what a verdict adds from
    the prediction (its variance where the match is blind, or the cover of a step it
    repeats), which would count the prediction twice when the two are weighed
    (:func:`.motion.model.fused_with_prediction`).
    """
    covariance = match.covariance + match.extra.get('surface_covariance', 0.0)
    return measured_only(covariance, match.information, length_scale,
                         config.degeneracy_min_information)


def judge_again(first: MatchVerdict, again: Registration, config: PipelineConfig,
                length_scale: float = 1.0) -> MatchVerdict:
    """Judge a match made again from a judged one (de-skewed with its measured motion).

    The second match starts at the first's pose with the scan's points moved by a few
    centimetres: it sharpens the pose, it cannot settle what made the first doubtful
    (poses that fit alike, a direction the scene does not constrain, a poor fit). So
    a degenerate first verdict stays degenerate: its covariance, grown by ``d d^T`` for
    the shift ``d`` to the second's pose (:func:`covering_covariance`), stands where the
    second's is smaller. Judged afresh, such steps came out ``matched`` with
    centimetres of covariance. Kept degenerate, the simulated fast hall (3 seeds,
    plicp, nicp and imls; measured before :class:`.deskew.SweepTwist`) had 9 silent
    failed steps instead of 18 scan to scan and 9 instead of 29 against the local map,
    on the same trajectories.

    A second match that had to search (its match from the first pose failed) says
    that the step depends on how the sweep was de-skewed: the scan de-skewed with the
    measured twist no longer fits near the first pose. Where the motion changes within
    the sweep (a turn in place that starts or stops at 20 rad/s^2, 5 Hz), neither
    twist is the sweep's, and the scans warped either way fit a pose apart from the
    true one. The second pose stands; its covariance covers the first
    (:func:`covering_covariance`). Measured on the simulated hall, office, campus and
    corridor, ``spin`` and ``aggressive`` motion, seeds 1-2, noise copy 1, plicp,
    nicp and imls: silent failed steps 20 -> 10 of 121 failed (hall ``spin`` nicp scan
    373: 1.46 m off, NEES 405 -> 2.0; office ``spin`` imls scan 231: 11.5 deg off,
    NEES 1080 -> 4.2); no pose moved. The real logs carry no sweep timing: they are
    never matched again.
    """
    second = judge_match(again, first.pose, config, length_scale)
    if second.status == 'rejected':
        return second
    if again.searched:
        second = MatchVerdict(second.pose, covering_covariance(
            second.pose, second.covariance, [first.pose]), second.status)
    if first.status != 'degenerate':
        return second
    covariance = covering_covariance(second.pose, first.covariance, [first.pose])
    return MatchVerdict(second.pose, covering_both(covariance, second.covariance),
                        'degenerate')


def covering_both(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Return ``first + (second - first)_+``: at least as wide as both in every direction.

    ``(.)_+`` keeps the positive eigenvalues of the symmetric difference.
    """
    difference = 0.5 * ((second - first) + (second - first).T)
    values, vectors = np.linalg.eigh(difference)
    out = first + (vectors * np.maximum(values, 0.0)) @ vectors.T
    return 0.5 * (out + out.T)


def rejected_covariance(window: SearchWindow) -> np.ndarray:
    """Return the step covariance of a rejected match: the motion is anywhere in the window.

    The window is where the motion can be (it grows with the time since the last good
    match at the robot's top speed and turn rate), so its half-widths are the step's
    standard deviations in x, y and heading: the held or predicted pose says nothing
    more.
    """
    return np.diag([window.linear ** 2, window.linear ** 2, window.angular ** 2])


def _weakly_constrained(match: MatchResult, verdict: MatchVerdict,
                        config: AcceptanceConfig, length_scale: float) -> MatchVerdict:
    """Grow the covariance by what the evidence says the matcher's does not cover.

    ``surface_covariance`` in the match's extras is the spread of the search's score
    surface beyond its grid (:mod:`laser_odom.core.uncertainty.evidence`). It is
    added; when it exceeds the degeneracy threshold in some direction (a standard
    deviation above 5 cm by default) the match is weakly constrained: reported
    ``degenerate`` (its covariance is ignorance there, which compounds as independent)
    and flagged ``weak``.
    """
    grown = match.extra.get('surface_covariance')
    if grown is None or not np.any(grown):
        return verdict
    covariance = verdict.covariance + grown
    values, _, weak = degenerate_directions(_information_of(grown), length_scale,
                                            config.degeneracy_min_information)
    if not np.any(weak & (values > 0.0)):
        return MatchVerdict(verdict.pose, covariance, verdict.status)
    match.extra['weak'] = True
    return MatchVerdict(verdict.pose, covariance, 'degenerate')


def _information_of(covariance: np.ndarray) -> np.ndarray:
    """Return the pseudo-inverse of a covariance: no information where it has no variance."""
    return np.linalg.pinv(0.5 * (covariance + covariance.T), hermitian=True)


def covering_covariance(pose: se2.Pose, covariance: np.ndarray,
                        alternatives: list[np.ndarray]) -> np.ndarray:
    """Return ``covariance + sum_k d_k d_k^T`` with ``d_k`` the offset to alternative k.

    Each alternative then lies within one standard deviation of ``pose``
    (``d^T (S + d d^T)^-1 d < 1``): the estimate admits it may be any of them.
    """
    out = np.array(covariance, dtype=float)
    for alternative in alternatives:
        offset = np.asarray(alternative, dtype=float) - pose
        offset[2] = se2.wrap_angle(offset[2])
        out = out + np.outer(offset, offset)
    return 0.5 * (out + out.T)


def _degeneracy(match: MatchResult, anchor: se2.Pose, config: AcceptanceConfig,
                length_scale: float, prediction: Prediction | None = None) -> MatchVerdict:
    """Keep a match, or its correction from ``anchor`` only along the directions it constrains.

    Along the weak directions the pose keeps ``anchor`` (the prediction) and a large
    variance - or, when a prediction with a measured error stands in
    (:mod:`laser_odom.core.motion.blind_prior`), that error, when smaller.
    """
    values, vectors, weak = degenerate_directions(
        match.information, length_scale, config.degeneracy_min_information)
    if not np.any(weak):
        return MatchVerdict(match.pose.copy(), match.covariance.copy(), 'matched')
    match.degenerate = True
    scale = metric_scale(length_scale)
    correction = match.pose - anchor
    correction[2] = se2.wrap_angle(correction[2])
    # Keep the correction only along the well-constrained directions (projection in
    # metric coordinates x' = S^-1 x, where the eigenvectors are orthonormal).
    strong = vectors[:, ~weak]
    pose = anchor + scale * (strong @ (strong.T @ (correction / scale)))
    pose[2] = se2.wrap_angle(pose[2])
    blind = np.full(len(values), DEGENERATE_VARIANCE)
    if prediction is not None:
        # The prediction's variance along each weak direction, in metric units.
        metric = prediction.covariance / scale[:, None] / scale[None, :]
        blind = np.minimum(blind, np.einsum('ik,ij,jk->k', vectors, metric, vectors))
        match.extra['predicted'] = prediction.source
    variances = np.where(weak, blind, 1.0 / np.maximum(values, 1e-300))
    metric_covariance = (vectors * variances) @ vectors.T
    covariance = (metric_covariance * scale[:, None]) * scale[None, :]
    return MatchVerdict(pose, 0.5 * (covariance + covariance.T), 'degenerate')
