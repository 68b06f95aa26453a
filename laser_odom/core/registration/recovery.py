"""The global search that recovers a match: search, refine the peaks, choose by the fit.

When the prediction cannot be trusted or the match from it failed
(:mod:`laser_odom.core.registration.registrar`), the correlative search
(:mod:`laser_odom.core.search`) scores the window and the matcher refines its best few
poses. The window adapts: the configured one first; then, when the robot can have gone
farther since the last good match, the window it can have reached at its top speed and
turn rate (:meth:`.GlobalSearchConfig.window`); and once more, twice as wide, when the
pose chosen lies at the window's edge or fits poorly. The candidates of every search
compete, compared by one matcher-independent measure - how well the current points
fall on the reference surface (:func:`surface_fit`) - so correct evidence far from a
wrong prediction wins over it. A pose beyond the configured window is a larger motion,
less likely a priori: it must fit clearly better (by ``1 / global_search_ambiguity``)
and fit well (``global_search_poor_fit``) to be preferred to a nearer one; otherwise a
grown window's far peaks, which fit a little better by chance where the scans share
little, would win. Distinct poses that fit alike
are kept as alternatives (a symmetric room, a featureless corridor), and the spread of
the search's score surface about the chosen pose is measured
(:mod:`laser_odom.core.uncertainty.evidence`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Callable

import numpy as np

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import PipelineConfig
from laser_odom.core.matchers import MatchResult
from laser_odom.core.motion.blind_prior import Prediction
from laser_odom.core.registration.rejection import searched_rejection_reason
from laser_odom.core.scan.laser_scan import ScanPoints
from laser_odom.core.search import correlative_search, SearchResult, SearchWindow
from laser_odom.core.search.correlative import KEEP_RATIO, pose_distance, search_points
from laser_odom.core.uncertainty.evidence import surface_covariance

SURFACE_SPAN = 4.6
"""The search keeps every pose whose likelihood is at least exp(-4.6) = 1 % of the best's
(besides those within ``KEEP_RATIO`` of the best score): the rest weighs nothing in the
spread of the score surface (:mod:`laser_odom.core.uncertainty.evidence`)."""


@dataclass
class Choice:
    """What the searches found.

    ``match`` is the chosen candidate (None when none converged), ``search`` the last
    search's result, ``window`` its window, ``candidates`` how many were refined,
    ``alternatives`` the distinct poses that fit alike with their fit ratios,
    ``widened`` whether the window was searched once more, twice as wide.
    """

    match: MatchResult | None
    search: SearchResult | None
    window: SearchWindow
    candidates: int
    alternatives: list[tuple[np.ndarray, float]] = field(default_factory=list)
    widened: bool = False


Refine = Callable[[se2.Pose], MatchResult]
"""The matcher run from a pose (errors caught, its covariance calibration applied)."""


def search_and_choose(refine: Refine, reference: ScanPoints, current: ScanPoints,
                      guess: se2.Pose, config: PipelineConfig, elapsed: float,
                      local: MatchResult | None, trusted: bool,
                      prediction: Prediction | None) -> Choice:
    """Search the windows around ``guess`` and choose among every refined candidate.

    ``elapsed`` [s] is the time since the last good match (the window grows with it);
    ``local`` the match from a trusted prediction, when it converged, competes too.
    """
    search = config.search
    base, grown = search.window(), search.window(elapsed)
    windows = [base] if grown == base else [base, grown]
    candidates = [] if local is None else [local]
    choice = None
    for window in windows:
        choice = _round(refine, reference, current, guess, config, window, candidates,
                        local, trusted, prediction, choice)
    wider = search.widened(windows[-1])
    if wider is not None and search_further(choice, guess, config):
        choice = _round(refine, reference, current, guess, config, wider, candidates,
                        local, trusted, prediction, choice)
        choice.widened = True
    return choice


def _round(refine: Refine, reference: ScanPoints, current: ScanPoints, guess: se2.Pose,
           config: PipelineConfig, window: SearchWindow, candidates: list[MatchResult],
           local: MatchResult | None, trusted: bool, prediction: Prediction | None,
           last: Choice | None) -> Choice:
    """Search ``window``, add its refined peaks to ``candidates``, choose among all."""
    search = config.search
    result = correlative_search(
        reference, current, guess, window, search.global_search_candidates,
        min(KEEP_RATIO, search.global_search_ambiguity),
        SURFACE_SPAN / search.global_search_effective_points)
    if result is not None:
        refined = [refine(peak.pose) for peak in result.peaks]
        if last is not None:
            # The configured window was searched first: a grown window adds the
            # motions beyond it, not second opinions within it.
            refined = [m for m in refined if _beyond(m, guess, config)]
        candidates += refined
    elif last is not None:
        result = last.search
    return choose(reference, current, guess, config, window, result, candidates, local,
                  trusted, prediction)


def _beyond(match: MatchResult, guess: se2.Pose, config: PipelineConfig) -> bool:
    """Tell whether a converged match lies beyond the configured window."""
    offset = np.asarray(match.pose, dtype=float) - guess
    window = config.search.window()
    slack = window.resolution
    return bool(max(abs(offset[0]), abs(offset[1])) > window.linear + slack
                or abs(float(se2.wrap_angle(offset[2]))) > window.angular + slack)


def search_further(choice: Choice, guess: se2.Pose, config: PipelineConfig) -> bool:
    """Tell whether the chosen pose lies at the window's edge or fits poorly."""
    match, window = choice.match, choice.window
    if match is None:
        return True
    if match.extra.get('surface_fit', 0.0) < config.search.global_search_poor_fit:
        return True
    offset = np.asarray(match.pose, dtype=float) - guess
    edge = max(abs(offset[0]), abs(offset[1])) >= window.linear - window.resolution
    turned = abs(float(se2.wrap_angle(offset[2])))
    return bool(edge or (window.angular < math.pi
                         and turned >= window.angular - window.resolution))


def choose(reference: ScanPoints, current: ScanPoints, guess: se2.Pose,
           config: PipelineConfig, window: SearchWindow, result: SearchResult | None,
           candidates: list[MatchResult], local: MatchResult | None, trusted: bool,
           prediction: Prediction | None) -> Choice:
    """Judge the refined candidates by their surface fit (module docstring).

    Among candidates that fit alike, the one nearest the trusted guess, or else the
    blind prediction's translation, is taken.
    """
    search = config.search
    choice = Choice(None, result, window, len(candidates))
    converged = [m for m in candidates if m.converged and se2.is_finite_pose(m.pose)]
    if not converged:
        return choice
    # Every candidate is measured on the reference surface, the same way whatever the
    # matcher; those inside the window and on the surface enough compete first (the
    # window is the gate they are judged by). A matcher's own inlier ratio would drop
    # correct poses a metre away, where its pair gates cut.
    points = search_points(current, window.resolution)
    for m in converged:
        m.extra['surface_fit'], m.extra['surface_overlap'] = surface_fit(
            reference, points, m.pose, window.kernel_sigma)
    pool = [m for m in converged if searched_rejection_reason(
        m, guess, config.acceptance, window) is None] or converged
    fits = np.array([m.extra['surface_fit'] for m in pool])
    scale = result.length_scale if result is not None else current.length_scale
    separation = result.separation if result is not None else 3.0 * window.resolution
    ambiguity = search.global_search_ambiguity
    far = np.array([_beyond(m, guess, config) for m in pool])
    weighed = np.where(far, ambiguity * fits, fits)
    if not far.all():
        # A far pose that fits poorly is no evidence of a larger motion.
        weighed[far & (fits < search.global_search_poor_fit)] = 0.0
    best = int(np.argmax(weighed))
    anchor = guess if trusted else (None if prediction is None else prediction.pose)
    if anchor is not None and (trusted or fits[best] >= search.global_search_poor_fit):
        # Among poses the scans cannot tell apart, the one nearest a trusted prediction
        # is the best guess (nearest the last step's translation: its turn is not
        # predicted; and only among poses that fit well - a robot that reverses is not
        # where it went before).
        alike = weighed >= ambiguity * weighed[best]
        if not trusted:  # the same turn: the last step cannot tell turns apart
            turns = np.array([se2.wrap_angle(m.pose[2] - pool[best].pose[2]) for m in pool])
            alike &= np.abs(turns) * scale <= separation
        alike = np.flatnonzero(alike)
        near = pose_distance(np.array([pool[i].pose for i in alike]), anchor,
                             scale if trusted else 0.0)
        best = int(alike[int(np.argmin(near))])
    at = next((i for i, m in enumerate(pool) if m is local), None)
    if at is not None and fits[at] >= ambiguity * fits[best] and \
            pose_distance(local.pose, pool[best].pose, scale)[0] <= separation:
        # The fit tells solutions apart, not millimetres within one: when the match from
        # the prediction converged to the chosen solution, it stands. Near it but fitting
        # worse, it is another (intel's keyframes 0.1 s apart, plicp, scan 835: 13 deg
        # short of a 33 deg turn at a fit of 0.68 against the search's 0.80, and taken).
        best = at
    chosen = pool[best]
    if result is not None:
        chosen.extra['surface_covariance'] = surface_covariance(
            result.poses, result.scores, chosen.pose, search.global_search_effective_points,
            window.resolution, scale)
    choice.match = chosen
    choice.alternatives = distinct_alternatives(
        pool, fits / max(float(fits[best]), 1e-12), chosen.pose, scale, separation,
        ambiguity)
    return choice


def surface_fit(reference: ScanPoints, points: np.ndarray, pose: se2.Pose,
                sigma: float) -> tuple[float, float]:
    """Return how well ``points`` moved by ``pose`` lie on the reference surface.

    The fit is the mean of ``exp(-d^2 / 2 sigma^2)`` over the points, ``d`` each one's
    distance to the nearest reference point - the search's likelihood, evaluated
    exactly at a refined pose; the overlap is the fraction with ``d <= 2 sigma``. Both
    compare candidates and judge matches whatever the matcher and its residual metric.
    """
    if len(points) == 0 or len(reference) == 0:
        return 0.0, 0.0
    distance, _ = reference.bearing_index.nearest(se2.transform_points(pose, points),
                                                  4.0 * sigma)
    fit = float(np.mean(np.exp(-0.5 * np.square(distance / sigma))))
    return fit, float(np.mean(distance <= 2.0 * sigma))


def distinct_alternatives(candidates: list[MatchResult], fit_ratios: np.ndarray,
                          chosen: se2.Pose, length_scale: float, separation: float,
                          ambiguity: float) -> list[tuple[np.ndarray, float]]:
    """Return the candidates that fit at least ``ambiguity`` as well as the chosen pose.

    Only those farther than ``separation`` from the chosen pose and from each other
    (rotation measured as the arc at ``length_scale``) count, with their fit ratio.
    """
    alternatives: list[tuple[np.ndarray, float]] = []
    for match, ratio in zip(candidates, fit_ratios):
        distinct = all(pose_distance(match.pose, other, length_scale)[0] > separation
                       for other in [chosen] + [pose for pose, _ in alternatives])
        if distinct and ratio >= ambiguity:
            alternatives.append((match.pose.copy(), float(ratio)))
    return alternatives
