"""Registration: the matcher from the prediction, and the global search that recovers it.

A prediction is a guess. When it is trusted (the constant-velocity or wheel-odometry
step after an accepted match) the matcher starts from it, and its result is checked:
converged, enough of the scan paired, a residual and an inlier ratio near their usual
level, and a correction inside ``max_correction_*``. When the prediction cannot be trusted (the
first match, a gap longer than ``max_scan_gap``, ``prior: none``, right after a
rejection), or the local match failed one of those checks, the global search
(:mod:`laser_odom.core.registration.recovery`) scores the windows around the prediction and the
matcher refines their best few poses; the candidate whose points fit the reference
surface best is chosen, and distinct poses that fit alike are reported (a symmetric
room, a featureless corridor) instead of one being taken silently. The registrar also
keeps what a match is judged against: the usual fit of recent matches, the time since
the last good one (the window grows with it) and the steps the blind prediction is
measured on (:mod:`laser_odom.core.motion.blind_prior`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import math

import numpy as np

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import PipelineConfig
from laser_odom.core.events import EventLog
from laser_odom.core.matchers import MatchResult, ScanMatcher
from laser_odom.core.motion.blind_prior import Prediction, StepHistory
from laser_odom.core.registration.basins import other_basins, record_other_basins
from laser_odom.core.registration.doubt import PredictionDoubt
from laser_odom.core.registration.recovery import search_and_choose
from laser_odom.core.registration.rejection import (
    correction_from, describe_rejection, rejection_reason)
from laser_odom.core.registration.usual import UsualLevel
from laser_odom.core.scan.laser_scan import ScanPoints
from laser_odom.core.search import SearchResult, SearchWindow

SEARCH_TRIGGERS = {
    'reset': 'first match after a start, reset or time jump: no prediction yet',
    'gap': 'the motion prior was dropped after a gap between scans',
    'no_prior': 'prior is none: every match starts with the global search',
    'rejected': 'the previous match was rejected, so its prediction is not trusted',
    'poor_fit': 'the previous match fitted poorly, so its motion predicts nothing',
    'local_failed': 'the match from the prediction failed',
    'doubtful': 'the prediction is a step too large or too uncertain for the matcher '
                'alone: its match is checked against the search',
    'always': 'global_search is always',
}
"""Why the global search ran, by trigger name (counted as ``search_<trigger>``)."""

WEAK_FLAGS = ('weak', 'ambiguous', 'poor_fit', 'predicted')
"""Extras of a match that was not well constrained
(:mod:`laser_odom.core.registration.acceptance`)."""

ROUTINE_TRIGGERS = ('reset', 'no_prior', 'always', 'doubtful')
"""Triggers that are how the odometry is meant to run: counted, not warned about."""


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
    window: SearchWindow | None = None
    """The window searched (grown with the time since the last good match, and once
    more when the best pose lay at its edge or fitted poorly); None when no search ran."""
    widened: bool = False
    """Whether the window was searched a second time, twice as wide."""
    prediction: Prediction | None = None
    """What stands in where the scan is blind (:mod:`laser_odom.core.motion.blind_prior`): the
    trusted guess, or with no trusted guess the last well-constrained step's motion."""

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
        window = self.window
        wide = '' if window is None else (
            f' in a window of +-{window.linear:.1f} m / +-{math.degrees(window.angular):.0f} deg'
            + (', searched again twice as wide' if self.widened else ''))
        return (f'best of {self.candidates} refined candidates{wide}: {linear:.2f} m / '
                f'{math.degrees(angular):.1f} deg from the prediction, fit {fit:.2f} '
                f'(search score {self.search.best.score:.2f})')

    def describe_alternatives(self) -> str:
        """Say how far the closest-fitting alternative lies and how well it fits."""
        pose, ratio = max(self.alternatives, key=lambda item: item[1])
        linear, angular = correction_from(self.match.pose, pose)
        return (f'a pose {linear:.2f} m / {math.degrees(angular):.1f} deg away fits '
                f'{ratio:.0%} as well (featureless corridor or symmetric room?)')


class Registrar:
    """Runs the matcher, and the global search when the prediction or the match fails."""

    def __init__(self, events: EventLog) -> None:
        """Create the registrar; matcher errors are reported to ``events``."""
        self.events = events
        self.usual = UsualLevel()
        self.lost_since_ns: int | None = None
        """Stamp of the reference of the first match not accepted since the last good
        match (None while matches are accepted)."""
        self._started_ns: int | None = None
        """The reference stamp a registration started from, until it is accepted."""
        self.elapsed_s = 0.0
        """Seconds from the last good match to the scan being registered."""
        self.history = StepHistory()
        self.doubt = PredictionDoubt()
        """How far recent trusted predictions missed (:mod:`.doubt`)."""
        self._stamps = (0, 0)
        """Stamps of the reference and the current scan being registered."""
        self.carried = np.zeros((3, 3))
        """Covariance of the trusted guess's error beyond the measured one (:meth:`expect`)."""

    def expect(self, carried: np.ndarray) -> None:
        """Take what the next trusted guess carries from a step not well constrained.

        :meth:`.MotionModel.carried_covariance`: the constant velocity of a degenerate
        step carries its error on, which the prediction's measured error (consecutive
        well-constrained steps) does not hold. It is added to that error
        (:meth:`predict`), so that where the next match is blind the estimate admits
        it (the simulated fast hall, plicp: a 1.5 m alias along the aisle, announced,
        carried on by the next prediction and published with a 1 cm variance there:
        NEES 165).
        """
        self.carried = np.array(carried, dtype=float)

    def elapsed(self, reference: ScanPoints, current: ScanPoints) -> float:
        """Return the seconds since the last good match: the window grows with them.

        That is the time since the reference scan, or since the reference of the
        first match that was not accepted after the last good one (the pipeline calls
        :meth:`accepted` for every accepted match).
        """
        if self._started_ns is not None:  # the previous registration was not accepted
            self.lost_since_ns = self._started_ns
        start = reference.stamp_ns if self.lost_since_ns is None else min(
            self.lost_since_ns, reference.stamp_ns)
        self._started_ns = start
        return max(0.0, (current.stamp_ns - start) * 1e-9)

    def register(self, matcher: ScanMatcher, reference: ScanPoints, current: ScanPoints,
                 guess: se2.Pose, config: PipelineConfig, untrusted: str,
                 local: MatchResult | None = None, verify: bool = True) -> Registration:
        """Match ``current`` against ``reference`` from ``guess``.

        ``untrusted`` names why the prediction cannot be trusted ('' when it can).
        ``local`` is the match from the prediction when it was already made
        (:meth:`try_local`). A trusted prediction in doubt (:mod:`.doubt`) has its
        match checked by the search; ``verify=False`` skips that, for a guess that is
        itself a match just found (matched again after de-skewing).
        """
        if local is None:  # else try_local began this registration
            self._begin(reference, current)
        if untrusted:  # the next trusted prediction has no record yet
            self.doubt.clear()
        prediction = self.predict(guess, untrusted, reference, current)
        mode = config.search.global_search
        if mode == 'always' or (mode == 'recover' and untrusted):
            if mode == 'always' and local is None:
                local = self.local_match(matcher, reference, current, guess, not untrusted)
            elif mode != 'always':
                local = None
            registration = self._search(matcher, reference, current, guess, config,
                                        'always' if mode == 'always' else untrusted, local,
                                        '', not untrusted, prediction)
        else:
            if local is None:
                local = self.local_match(matcher, reference, current, guess, True)
            failure = self.local_failure(local, guess, config, reference.virtual)
            doubt = '' if failure or not verify else (
                self.doubt.doubt(guess, config.acceptance)
                or self.doubt.would_surprise(guess, local.pose))
            if (failure or doubt) and mode == 'recover':
                registration = self._search(matcher, reference, current, guess, config,
                                            'local_failed' if failure else 'doubtful',
                                            local, failure, True, prediction)
                registration.failure_detail = (
                    self.describe_failure(failure, local, guess, config) if failure
                    else doubt)
            else:
                registration = Registration(local, local_failure=failure)
                if not failure:
                    self.check_basins(matcher, reference, current, guess, local, config)
        if not untrusted and verify and registration.match.converged:
            self.doubt.record(guess, registration.match.pose,
                              [pose for pose, _ in registration.alternatives],
                              registration.local_failure)
        registration.prediction = prediction
        return registration

    def predict(self, guess: se2.Pose, untrusted: str, reference: ScanPoints,
                current: ScanPoints) -> Prediction | None:
        """Return what stands in where the scan is blind, with its measured error.

        The trusted guess, or, when it is not trusted, the last well-constrained step's
        motion if the scans come at a steady rate; None without enough history.
        """
        if not untrusted:
            covariance = self.history.covariance(self.elapsed_s)
            return None if covariance is None else Prediction(
                np.array(guess, dtype=float), covariance + self.carried, 'prior',
                bool(np.any(self.carried)))
        return self.history.last_step(reference.stamp_ns, current.stamp_ns)

    def try_local(self, matcher: ScanMatcher, reference: ScanPoints, current: ScanPoints,
                  guess: se2.Pose, config: PipelineConfig) -> tuple[Registration, bool]:
        """Run the match from a trusted prediction; return it and whether it passed.

        Passed: no :meth:`local_failure` and the prediction not in doubt
        (:mod:`.doubt`; a short record is no doubt here: the local map's registrars
        match from a prediction only now and then), the result :meth:`register`
        would return without searching (with ``global_search: always`` nothing passes
        here). When it did not pass,
        :meth:`register` goes on with its match (``local``).
        """
        self._begin(reference, current)
        local = self.local_match(matcher, reference, current, guess, True)
        passed = (config.search.global_search != 'always'
                  and not self.local_failure(local, guess, config, reference.virtual)
                  and not self.doubted(local, guess, config, reference.virtual))
        if passed:
            self.doubt.record(guess, local.pose)
            self.check_basins(matcher, reference, current, guess, local, config)
        registration = Registration(local)
        registration.prediction = self.predict(guess, '', reference, current)
        return registration, passed

    def doubted(self, match: MatchResult, guess: se2.Pose, config: PipelineConfig,
                against_map: bool = False) -> str:
        """Return why a match from a trusted ``guess`` that passed its checks is not taken.

        The prediction, not the match, is in doubt (:mod:`.registration.doubt`; its
        record, not the short-record rule: a second-opinion registrar matches only now
        and then); '' when the match stands, or failed its own checks, or the global
        search is not ``recover``.
        """
        if (config.search.global_search != 'recover'
                or self.local_failure(match, guess, config, against_map)):
            return ''
        return self.doubt.doubt(guess, config.acceptance, False)

    def refine(self, matcher: ScanMatcher, reference: ScanPoints, current: ScanPoints,
               found: Registration, config: PipelineConfig) -> Registration | None:
        """Refine a step found against another reference; None if the refinement failed.

        The matcher starts from ``found``'s pose as from a trusted prediction, and the
        refined match is checked like one (:meth:`local_failure`: converged, paired,
        fitting about as usual, within ``max_correction_*`` of that pose). It keeps
        how the step was found (the search, its window, the prediction, the poses
        that fitted alike), so it is judged as that searched step.
        """
        self._begin(reference, current)
        self.doubt.clear()  # found without a trusted prediction
        start = found.match.pose
        refined = self.local_match(matcher, reference, current, start, True)
        if self.local_failure(refined, start, config, reference.virtual):
            return None
        return replace(found, match=refined, local_failure='', failure_detail='')

    def _begin(self, reference: ScanPoints, current: ScanPoints) -> None:
        """Start registering ``current`` against ``reference``: the time and the stamps."""
        self.elapsed_s = self.elapsed(reference, current)
        self._stamps = (reference.stamp_ns, current.stamp_ns)

    def settled(self) -> None:
        """Record that the step was accepted from another reference: nothing was lost."""
        self.lost_since_ns = self._started_ns = None

    def accepted(self, match: MatchResult, status: str = 'matched') -> None:
        """Record an accepted match: its fit joins the scans' usual level.

        A well-constrained one (judged ``matched``; not degenerate, weak, ambiguous
        or poorly fitting) joins the step history the blind prediction is measured
        on. The judged ``status`` counts as well as the match's flags: a match made
        again after de-skewing may look clean by itself while its step stays
        degenerate (:func:`.acceptance.judge_again`), and a 1.5 m alias taken as a
        well-constrained velocity made the prediction's error look like 0.35 m.
        """
        self.usual.add(match)
        self.lost_since_ns = self._started_ns = None
        well = status == 'matched' and not (
            match.degenerate or any(match.extra.get(flag) for flag in WEAK_FLAGS))
        self.history.add(*self._stamps, match.pose, well)

    def local_failure(self, match: MatchResult, guess: se2.Pose,
                      config: PipelineConfig, against_map: bool = False) -> str:
        """Return why a match from a trusted prediction failed, '' if it did not.

        A match ``against_map`` (the local map's view) is not held to the usual share
        of paired points: the map covers what it has seen, so a scan that sees new
        ground (around a corner, through a door) pairs fewer of its points than usual
        with a pose just as right. Measured on fr079, that test failed 15 % of the
        map matches (nicp) and handed those steps to the previous scan, a branch that
        1 mm of range noise flipped; the absolute ``min_inlier_ratio`` and the usual
        residual still judge the fit.
        """
        reason = rejection_reason(match, guess, config.acceptance)
        if reason is not None:
            return reason
        acceptance = config.acceptance
        residual, inliers = self.usual.residual(), self.usual.inlier_ratio()
        if (residual is not None and acceptance.max_residual_ratio > 0.0
                and match.residual > acceptance.max_residual_ratio * residual):
            return 'high_residual'
        if (inliers is not None and not against_map
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

    def check_basins(self, matcher: ScanMatcher, reference: ScanPoints,
                     current: ScanPoints, guess: se2.Pose, match: MatchResult,
                     config: PipelineConfig) -> None:
        """Record the other basins of a match from the prediction (:mod:`.basins`).

        A start's match counts when it passes :meth:`local_failure` from that start.
        """
        def rematch(start: se2.Pose) -> MatchResult | None:
            landed = self.local_match(matcher, reference, current, start, True)
            return None if self.local_failure(landed, start, config,
                                              reference.virtual) else landed

        record_other_basins(match, other_basins(rematch, match, guess, current.length_scale,
                                                self.carried), self.events)

    def local_match(self, matcher: ScanMatcher, reference: ScanPoints,
                    current: ScanPoints, guess: se2.Pose,
                    predicted: bool = False) -> MatchResult:
        """Run the matcher; an internal error becomes a failed match, never a crash.

        From a trusted prediction (``predicted``) it refines the prediction
        (:meth:`.ScanMatcher.match_from_prediction`), else it matches from a far guess.

        Odometry must keep running on input nobody foresaw; the error is counted as
        ``matcher_error`` and said (throttled) so that it gets reported and fixed.
        The matcher's ``covariance_scale`` calibration is applied here, once for all.
        """
        try:
            run = matcher.match_from_prediction if predicted else matcher.match
            match = run(reference, current, guess)
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
                local: MatchResult | None, failure: str, trusted: bool,
                prediction: Prediction | None) -> Registration:
        """Search the windows, refine the best poses, keep the candidate that fits best.

        :func:`.recovery.search_and_choose`; its refinements are :meth:`local_match`.
        """
        choice = search_and_choose(
            lambda pose: self.local_match(matcher, reference, current, pose), reference,
            current, guess, config, self.elapsed_s, local, trusted, prediction)
        match = choice.match
        if match is None:
            match = local if local is not None else MatchResult.failure(
                guess, reason='search found nothing' if choice.search is None else '')
        return Registration(match, trigger, failure, search=choice.search,
                            alternatives=choice.alternatives, candidates=choice.candidates,
                            trusted=trusted, window=choice.window, widened=choice.widened)
