"""Registration: the matcher from the prediction, and the global search that recovers it.

A prediction is a guess. When it is trusted (the constant-velocity or wheel-odometry
step after an accepted match) the matcher starts from it, and its result is checked:
converged, enough of the scan paired, a residual and an inlier ratio near their usual
level, and a correction inside ``max_correction_*``. When the prediction cannot be trusted (the
first match, a gap longer than ``max_scan_gap``, ``prior: none``, right after a
rejection), or the local match failed one of those checks, the correlative search
(:mod:`laser_odom.core.search`) scores the whole window around the prediction and the
matcher refines its best few poses. The refined candidates, and the local match when
it converged, are compared by one matcher-independent measure - how well the current
points fall on the reference surface (:func:`surface_fit`) - so correct evidence far
from a wrong prediction wins over it, and two distinct poses that fit alike are found
and reported (a symmetric room, a featureless corridor) instead of one being taken
silently.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
import math
import statistics

import numpy as np

from laser_odom.core import se2
from laser_odom.core.acceptance import (
    correction_from, describe_rejection, rejection_reason, searched_rejection_reason)
from laser_odom.core.config import PipelineConfig
from laser_odom.core.events import EventLog
from laser_odom.core.matchers import MatchResult, ScanMatcher
from laser_odom.core.scan import ScanPoints
from laser_odom.core.search import correlative_search, SearchResult
from laser_odom.core.search.correlative import KEEP_RATIO, pose_distance, search_points

SEARCH_TRIGGERS = {
    'reset': 'first match after a start, reset or time jump: no prediction yet',
    'gap': 'the motion prior was dropped after a gap between scans',
    'no_prior': 'prior is none: every match starts with the global search',
    'rejected': 'the previous match was rejected, so its prediction is not trusted',
    'local_failed': 'the match from the prediction failed',
    'always': 'global_search is always',
}
"""Why the global search ran, by trigger name (counted as ``search_<trigger>``)."""

ROUTINE_TRIGGERS = ('reset', 'no_prior', 'always')
"""Triggers that are how the odometry is meant to run: counted, not warned about."""

RESIDUAL_WINDOW = 50
"""Accepted matches whose fit makes the usual level (the medians)."""

MIN_RESIDUAL_SAMPLES = 10
"""The checks against the usual level start once this many matches were accepted."""


class UsualLevel:
    """How accepted matches usually fit: medians of recent residuals and inlier ratios."""

    def __init__(self) -> None:
        """Start with no history."""
        self._residuals: deque[float] = deque(maxlen=RESIDUAL_WINDOW)
        self._inliers: deque[float] = deque(maxlen=RESIDUAL_WINDOW)

    def clear(self) -> None:
        """Forget the history (a new matcher measures its fit differently)."""
        self._residuals.clear()
        self._inliers.clear()

    def add(self, match: MatchResult) -> None:
        """Record how an accepted match fits."""
        if math.isfinite(match.residual) and math.isfinite(match.inlier_ratio):
            self._residuals.append(float(match.residual))
            self._inliers.append(float(match.inlier_ratio))

    def residual(self) -> float | None:
        """Return the median recent residual, None before enough matches."""
        if len(self._residuals) < MIN_RESIDUAL_SAMPLES:
            return None
        return statistics.median(self._residuals)

    def inlier_ratio(self) -> float | None:
        """Return the median recent inlier ratio, None before enough matches."""
        if len(self._inliers) < MIN_RESIDUAL_SAMPLES:
            return None
        return statistics.median(self._inliers)


@dataclass
class Registration:
    """The match to judge and how it was found.

    ``trigger`` names why the global search ran ('' when it did not);
    ``local_failure`` why the match from the prediction was not trusted ('' when it
    was, or was not run) and ``failure_detail`` the numbers behind it.
    ``alternatives`` are refined poses distinct from the match that fit at least
    ``global_search_ambiguity`` as well, with their fit ratio. ``trusted`` tells
    whether the prediction was.
    """

    match: MatchResult
    trigger: str = ''
    local_failure: str = ''
    failure_detail: str = ''
    search: SearchResult | None = None
    alternatives: list[tuple[np.ndarray, float]] = field(default_factory=list)
    candidates: int = 0
    trusted: bool = True

    @property
    def searched(self) -> bool:
        """Tell whether the global search ran."""
        return bool(self.trigger)

    def outcome(self, guess: se2.Pose) -> str:
        """Say what the search found, relative to the prediction."""
        if self.search is None:
            return 'too few points to search'
        if not self.match.converged:
            return f'none of {self.candidates} refined candidates converged'
        linear, angular = correction_from(guess, self.match.pose)
        fit = self.match.extra.get('surface_fit', float('nan'))
        return (f'best of {self.candidates} refined candidates: {linear:.2f} m / '
                f'{math.degrees(angular):.1f} deg from the prediction, fit {fit:.2f} '
                f'(search score {self.search.best.score:.2f})')

    def describe_alternatives(self) -> str:
        """Say how far the closest-fitting alternative lies and how well it fits."""
        pose, ratio = max(self.alternatives, key=lambda item: item[1])
        linear, angular = correction_from(self.match.pose, pose)
        return (f'a pose {linear:.2f} m / {math.degrees(angular):.1f} deg away fits '
                f'{ratio:.0%} as well (featureless corridor or symmetric room?)')


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


class Registrar:
    """Runs the matcher, and the global search when the prediction or the match fails."""

    def __init__(self, events: EventLog) -> None:
        """Create the registrar; matcher errors are reported to ``events``."""
        self.events = events
        self.usual = UsualLevel()

    def register(self, matcher: ScanMatcher, reference: ScanPoints, current: ScanPoints,
                 guess: se2.Pose, config: PipelineConfig, untrusted: str,
                 local: MatchResult | None = None) -> Registration:
        """Match ``current`` against ``reference`` from ``guess``.

        ``untrusted`` names why the prediction cannot be trusted ('' when it can).
        ``local`` is the match from the prediction when it was already made
        (:meth:`try_local`).
        """
        mode = config.search.global_search
        if mode == 'always' or (mode == 'recover' and untrusted):
            if mode == 'always' and local is None:
                local = self.local_match(matcher, reference, current, guess)
            return self._search(matcher, reference, current, guess, config,
                                'always' if mode == 'always' else untrusted,
                                local if mode == 'always' else None, '',
                                trusted=not untrusted)
        if local is None:
            local = self.local_match(matcher, reference, current, guess)
        failure = self.local_failure(local, guess, config)
        if failure and mode == 'recover':
            registration = self._search(matcher, reference, current, guess, config,
                                        'local_failed', local, failure, trusted=True)
            registration.failure_detail = self.describe_failure(failure, local, guess, config)
            return registration
        return Registration(local, local_failure=failure)

    def try_local(self, matcher: ScanMatcher, reference: ScanPoints, current: ScanPoints,
                  guess: se2.Pose, config: PipelineConfig) -> tuple[MatchResult, bool]:
        """Run the match from a trusted prediction; return it and whether it passed.

        Passed: no :meth:`local_failure`, the result :meth:`register` would return
        without searching (with ``global_search: always`` nothing passes here).
        """
        local = self.local_match(matcher, reference, current, guess)
        passed = (config.search.global_search != 'always'
                  and not self.local_failure(local, guess, config))
        return local, passed

    def accepted(self, match: MatchResult) -> None:
        """Record an accepted match: its fit joins the scans' usual level."""
        self.usual.add(match)

    def local_failure(self, match: MatchResult, guess: se2.Pose,
                      config: PipelineConfig) -> str:
        """Return why a match from a trusted prediction failed, '' if it did not."""
        reason = rejection_reason(match, guess, config.acceptance)
        if reason is not None:
            return reason
        acceptance = config.acceptance
        residual, inliers = self.usual.residual(), self.usual.inlier_ratio()
        if (residual is not None and acceptance.max_residual_ratio > 0.0
                and match.residual > acceptance.max_residual_ratio * residual):
            return 'high_residual'
        if (inliers is not None
                and match.inlier_ratio < acceptance.min_relative_inlier_ratio * inliers):
            return 'few_inliers'
        return ''

    def describe_failure(self, reason: str, match: MatchResult, guess: se2.Pose,
                         config: PipelineConfig) -> str:
        """Return why the local match failed, with the numbers behind it."""
        residual, inliers = self.usual.residual(), self.usual.inlier_ratio()
        if reason == 'high_residual' and residual:
            return (f'residual {match.residual:.3f} m, {match.residual / residual:.1f}x the '
                    f'usual {residual:.3f} m')
        if reason == 'few_inliers' and inliers:
            return (f'{match.inlier_ratio:.0%} of the points paired against the usual '
                    f'{inliers:.0%}')
        return describe_rejection(reason, match, guess, config)

    def local_match(self, matcher: ScanMatcher, reference: ScanPoints,
                    current: ScanPoints, guess: se2.Pose) -> MatchResult:
        """Run the matcher; an internal error becomes a failed match, never a crash.

        Odometry must keep running on input nobody foresaw; the error is counted as
        ``matcher_error`` and said (throttled) so that it gets reported and fixed.
        The matcher's ``covariance_scale`` calibration is applied here, once for all.
        """
        try:
            match = matcher.match(reference, current, guess)
        except (ValueError, ArithmeticError, IndexError, np.linalg.LinAlgError) as error:
            self.events.warn('matcher_error', f'{matcher.name} failed on a scan: '
                             f'{error!r}')
            return MatchResult.failure(guess, reason='matcher_error')
        scale = matcher.config.covariance_scale
        if scale != 1.0:
            match.covariance = match.covariance * scale
            match.information = match.information / scale
        return match

    def _search(self, matcher: ScanMatcher, reference: ScanPoints, current: ScanPoints,
                guess: se2.Pose, config: PipelineConfig, trigger: str,
                local: MatchResult | None, failure: str, trusted: bool) -> Registration:
        """Search the window, refine the best poses, keep the candidate that fits best."""
        search_config = config.search
        window = search_config.window()
        result = correlative_search(
            reference, current, guess, window, search_config.global_search_candidates,
            min(KEEP_RATIO, search_config.global_search_ambiguity))
        candidates = [] if result is None else [
            self.local_match(matcher, reference, current, peak.pose) for peak in result.peaks]
        if local is not None:
            candidates.append(local)
        converged = [m for m in candidates if m.converged and se2.is_finite_pose(m.pose)]
        registration = Registration(local if local is not None else MatchResult.failure(
            guess, reason='search found nothing' if result is None else ''), trigger, failure,
            search=result, candidates=len(candidates), trusted=trusted)
        if not converged:
            return registration
        # Candidates inside the window first: the window is the gate they are judged by.
        pool = [m for m in converged if searched_rejection_reason(
            m, guess, config.acceptance, window) is None] or converged
        points = search_points(current, window.resolution)
        fits, overlaps = np.array([surface_fit(reference, points, m.pose,
                                               window.kernel_sigma) for m in pool]).T
        scale = result.length_scale if result is not None else current.length_scale
        separation = result.separation if result is not None else 3.0 * window.resolution
        ambiguity = search_config.global_search_ambiguity
        best = int(np.argmax(fits))
        if trusted:
            # Among poses the scans cannot tell apart, the one nearest a trusted
            # prediction is the best guess.
            alike = np.flatnonzero(fits >= ambiguity * fits[best])
            near = pose_distance(np.array([pool[i].pose for i in alike]), guess, scale)
            best = int(alike[int(np.argmin(near))])
        if local is not None and any(m is local for m in pool) and \
                pose_distance(local.pose, pool[best].pose, scale)[0] <= separation:
            # The fit tells solutions apart, not millimetres within one: when the match
            # from the prediction converged to the chosen solution, it stands.
            best = next(i for i, m in enumerate(pool) if m is local)
        chosen = pool[best]
        chosen.extra['surface_fit'] = float(fits[best])
        chosen.extra['surface_overlap'] = float(overlaps[best])
        registration.match = chosen
        registration.alternatives = distinct_alternatives(
            pool, fits / max(float(fits[best]), 1e-12), chosen.pose, scale, separation,
            ambiguity)
        return registration


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
