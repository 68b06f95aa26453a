"""Registration against the local map, with the previous scan as the second opinion.

With ``reference: local_map`` each scan is matched against the local map seen from
the previous pose (:mod:`laser_odom.core.registration.local_map.reference`). The map is the better
reference as long as it describes the scene; where it does not (the scene changed,
the map went wrong, the scan sees what the map dropped) the previous scan still does.
Both share the previous pose's frame, so one guess serves both and the result is the
step either way.

Without a trusted prediction (``prior: none``, the first match, after a gap or a
rejection), with one in doubt (:mod:`laser_odom.core.registration.doubt`), or when
neither reference gives a clean match from it, the step may be large, and the map
seen from the previous pose is a poor reference to search in: a virtual scan holds one
point per cell a bearing meets (a near wall gives fewer points than beams), and a map
just restarted holds one scan seen from afar. Measured on fr079 at every 10th scan
(steps of 0.5-1 m), the search against the view found the wrong pose on about a
quarter of the steps where the search against the previous scan found the right one.
So the step is searched for against the previous scan, as scan to scan does, and the
map then refines it from there like a trusted prediction: the map sharpens the step,
the scan finds it.
"""

from __future__ import annotations

from dataclasses import replace
from typing import NamedTuple

import numpy as np

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import PipelineConfig
from laser_odom.core.events import EventLog
from laser_odom.core.matchers import ScanMatcher
from laser_odom.core.registration.acceptance import judge_match, MatchVerdict
from laser_odom.core.registration.local_map.reference import fits_usual, MapReference, MAX_REFUSED
from laser_odom.core.registration.map_judging import (
    clean_match, match_rank, overshot_unproven, steps_agree)
from laser_odom.core.registration.recovery import surface_fit
from laser_odom.core.registration.registrar import Registrar, Registration
from laser_odom.core.scan.laser_scan import LaserScan, ScanPoints

MAP_EVENTS = ('map_fallback', 'map_restarted', 'map_disputed', 'map_refuted',
              'map_surprised')
"""Counted events of map matching: a step taken from the previous scan because it
fitted better than the map (``map_fallback``), the map started again from the current
scan (``map_restarted``: after a rejected match, or scans in a row fitting it poorly),
a map match that fitted poorly and that the previous scan contradicted
(``map_disputed``: its covariance covers both; ``map_refuted``: the previous scan's
step taken, as the map's step fitted it far worse and the map no better), a map match
that corrected a good prediction by far more than usual and was checked against the
previous scan (``map_surprised``)."""

REFUTING_FIT = 0.15
"""A disputed map step is refuted when the previous scan's own step fits that scan by
this much more (surface fit, :data:`SURPRISE_FIT_SIGMA`; a clean step fits it at 0.8-0.95)
and the map's view fits the map's step no better than the scan's
(:meth:`MapRegistrar._second_opinion`)."""

SURPRISE_FIT_SIGMA = 0.05
"""Kernel width [m] of the surface fit that settles a surprise: the two steps it tells
apart differ by decimetres (:meth:`MapRegistrar._settle_surprise`)."""


def settling_fit(reference: ScanPoints, current: ScanPoints, pose: se2.Pose) -> float:
    """Return how well ``current`` at ``pose`` lies on ``reference``, whatever the matcher.

    :func:`.recovery.surface_fit` with :data:`SURPRISE_FIT_SIGMA`: what settles a map
    step against the previous scan's (:meth:`MapRegistrar._settle_surprise`,
    :meth:`MapRegistrar._second_opinion`).
    """
    return surface_fit(reference, current.points, pose, SURPRISE_FIT_SIGMA)[0]


class JudgedMatch(NamedTuple):
    """A judged match, the reference it was made against and the registrar that made it."""

    reference: ScanPoints
    registrar: Registrar
    registration: Registration
    verdict: MatchVerdict
    from_map: bool = True
    """Whether it was made against the map (False: against the previous scan)."""
    found: Registration | None = None
    """The match against the previous scan that a map match was refined from (None
    when the map match started from the prediction)."""
    doubt: np.ndarray | None = None
    """Covariance (3x3) the step's error may have beyond the verdict's: ``d d^T`` of
    the difference ``d`` to the previous scan's match when the two disagreed
    (``map_disputed``); None when nothing disputes the match."""


class MapRegistrar:
    """Matches scans against the local map and keeps the map up to date."""

    def __init__(self, config: PipelineConfig, events: EventLog) -> None:
        """Create an empty map from ``config``; events are counted and said to ``events``."""
        self.map = MapReference(config.local_map, config.mounting.mounting())
        self.scan_registrar = Registrar(events)
        self.events = events

    def reset(self) -> None:
        """Forget the map and the previous scan."""
        self.map.reset()

    def observe_scan(self, scan: LaserScan) -> None:
        """Take the view's bearing bin and reach from the laser (:class:`MapReference`)."""
        self.map.observe_scan(scan)

    def restart(self, current: ScanPoints, pose: se2.Pose) -> None:
        """Start the map from ``current`` at ``pose`` (the first scan after a reset)."""
        self.map.restart(current, pose)

    def view(self, pose: se2.Pose, stamp_ns: int) -> ScanPoints:
        """Return the map seen from ``pose``, the reference of the next match."""
        return self.map.view(pose, stamp_ns)

    def register(self, matcher: ScanMatcher, registrar: Registrar, view: ScanPoints,
                 current: ScanPoints, guess: se2.Pose, config: PipelineConfig,
                 untrusted: str) -> JudgedMatch:
        """Match ``current`` against the map's ``view``, or the previous scan if better.

        From a trusted prediction the match against the map stands when it is clean
        (:func:`clean_match`); else the match against the previous scan when that is
        clean (counted as ``map_fallback``). When neither is, or the prediction itself
        is in doubt (also when the map's match moved far from a prediction not yet
        proven, :func:`overshot_unproven`), the previous scan finds the step as in scan
        mode and the map refines it (:meth:`_register_doubted`).
        Only without a previous scan (the map just started) does the full registration
        (:meth:`.Registrar.register`) search the map's view. ``registrar`` is the one
        that matches against the map (it keeps the usual fit of map matches).
        """
        previous = self.map.previous_scan
        scale = current.length_scale
        if untrusted and previous is not None:
            return self._register_untrusted(matcher, registrar, view, previous, current,
                                            guess, config, untrusted)
        local = None
        if not untrusted:
            registration, passed = registrar.try_local(matcher, view, current, guess, config)
            local = registration.match
            if passed:
                verdict = judge_match(registration, guess, config, scale)
                if clean_match(registration, verdict):
                    if previous is not None and overshot_unproven(registrar, local, guess,
                                                                  config):
                        return self._register_doubted(matcher, registrar, view, previous,
                                                      current, guess, config)
                    judged = JudgedMatch(view, registrar, registration, verdict)
                    if (matcher.config.map_surprise_check and previous is not None
                            and registrar.doubt.surprised()):
                        return self._settle_surprise(matcher, previous, current, guess,
                                                     config, judged)
                    if previous is None or fits_usual(local, registrar.usual.residual(),
                                                      None):
                        return judged
                    return self._second_opinion(matcher, previous, current, guess, config,
                                                judged)
            if previous is not None:
                if not (registrar.doubted(local, guess, config, True)
                        or overshot_unproven(registrar, local, guess, config)):
                    against_scan = self._clean_scan_match(matcher, previous, current, guess,
                                                          config)
                    if against_scan is not None:
                        return self._fallback(previous, *against_scan)
                return self._register_doubted(matcher, registrar, view, previous, current,
                                              guess, config)
        # No previous scan (the map just started): the map's view is all there is.
        registration = registrar.register(matcher, view, current, guess, config, untrusted,
                                          local)
        return JudgedMatch(view, registrar, registration,
                           judge_match(registration, guess, config, scale))

    def refine_on_surfaces(self, matcher: ScanMatcher, current: ScanPoints,
                           judged: JudgedMatch, view_pose: se2.Pose) -> JudgedMatch:
        """Refine a clean map match on the map's own surfaces (``map_surface_refine``).

        A match against the map's view (from ``view_pose``) that was judged
        ``matched`` is refined once more against the cells themselves
        (:mod:`.local_map.surface_fit`); its covariance and verdict stand. Degenerate,
        rejected and previous-scan matches are left as they are: their weak direction
        or their reference is not the map's to correct. It lowers the ATE of ``imls``
        and ``plicp`` on fr079, MIT CSAIL and Intel (docs/benchmark.md); ``nicp`` with
        ``map_surface_weak_share`` (:data:`.nicp.matcher.NICP_MAP_WEAK_SHARE`).
        """
        verdict = judged.verdict
        if not (matcher.config.map_surface_refine and judged.from_map
                and verdict.status == 'matched'):
            return judged
        step = self.map.refine_step(current.points, view_pose, verdict.pose,
                                    matcher.config.map_surface_weak_share)
        if step is None:
            return judged
        return judged._replace(verdict=replace(verdict, pose=step))

    def _register_doubted(self, matcher: ScanMatcher, registrar: Registrar,
                          view: ScanPoints, previous: ScanPoints, current: ScanPoints,
                          guess: se2.Pose, config: PipelineConfig) -> JudgedMatch:
        """Find the step when the map match from a trusted prediction cannot stand.

        The prediction recently missed, or predicts a step as large as the correction
        gate (:mod:`.registration.doubt`), or its match against the map failed while
        the previous scan's from the prediction is not clean either. The previous
        scan then finds the step exactly as scan-to-scan odometry does (the match from
        the prediction competes with the global search's, :meth:`.Registrar.register`)
        and the map refines it (:meth:`_register_untrusted`): searched against the map's
        view from afar, the step went wrong where scan mode found it (intel's keyframes
        0.1 s apart, plicp: 30 failed steps, 6 silent; scan mode 12, none silent). The
        step taken is recorded as the prediction's miss, so the doubt ends once the
        predictions hit again (recorded only for a match that passed, the map's
        registrar stayed in doubt: intel plicp took 2210 of 5505 steps from the
        previous scan, drift 1.1 -> 2.6 %).
        """
        judged = self._register_untrusted(matcher, registrar, view, previous, current, guess,
                                          config, '')
        if judged.verdict.status != 'rejected':
            registrar.doubt.record(guess, judged.verdict.pose)
        return judged

    def _second_opinion(self, matcher: ScanMatcher, previous: ScanPoints,
                        current: ScanPoints, guess: se2.Pose, config: PipelineConfig,
                        judged: JudgedMatch) -> JudgedMatch:
        """Check a clean map match that fits worse than usual against the previous scan.

        A match that pairs fewer points or leaves a larger residual than map matches
        usually do (:func:`.local_map.reference.fits_usual`) may have settled in a wrong
        minimum of the map from a poor prediction (fr079, icp: 10 deg off from a
        prediction 8 deg off, at twice the usual residual, judged clean and published
        with a covariance of 0.5 deg). The previous scan, matched from the same
        prediction, is a second opinion. When its match is clean, fits as its matches
        usually do, and disagrees with the map's beyond both covariances
        (:func:`steps_agree`), the step is in doubt. Each step is then measured on
        both references with the matcher-free surface fit of :meth:`_settle_surprise`.
        When the map's step fits the previous scan far worse than the scan's own
        (:data:`REFUTING_FIT`) and the map's view does not prefer it either, the map
        has gone wrong there and the previous scan's step is taken (``map_refuted``):
        fr079, imls, 5 copies with 1 mm range noise, the map's step was 3-6 deg off in
        such cases where the scan's was within 0.6 deg (50 m drift 0.32 [0.58] ->
        0.28 [0.34] %). Otherwise neither is the better evidence (taking the scan's
        always made mit-csail's plicp worse: a clean scan match 0.2 m off against a
        correct map match): the map's step stands, its covariance widened by ``d d^T``
        (``d`` the difference of the two steps, the :attr:`JudgedMatch.doubt`) so
        that it covers both, and the doubt is said (``map_disputed``).
        """
        against_scan = self._clean_scan_match(matcher, previous, current, guess, config)
        if against_scan is None:
            return judged
        registration, verdict = against_scan
        usual = self.scan_registrar.usual
        if not (fits_usual(registration.match, usual.residual(), usual.inlier_ratio())
                and not steps_agree(verdict, judged.verdict,
                                    matcher.config.map_covariance_scale)):
            return judged

        def fit(reference: ScanPoints, pose: se2.Pose) -> float:
            return settling_fit(reference, current, pose)
        if (fit(previous, verdict.pose) - fit(previous, judged.verdict.pose) > REFUTING_FIT
                and fit(judged.reference, judged.verdict.pose)
                <= fit(judged.reference, verdict.pose)):
            self.events.count('map_refuted')
            return self._fallback(previous, registration, verdict)
        difference = np.asarray(verdict.pose, dtype=float) - judged.verdict.pose
        difference[2] = se2.wrap_angle(difference[2])
        match = judged.registration.match
        self.events.warn('map_disputed', (
            f'at t={current.stamp_ns * 1e-9:.3f} the match against the local map '
            f'(residual {match.residual:.3f} m, '
            f'{match.inlier_ratio:.0%} paired) and the one against the previous scan '
            f'differ by {np.hypot(difference[0], difference[1]):.3f} m, '
            f'{np.degrees(abs(difference[2])):.1f} deg: the step keeps the map match, '
            'with a covariance that covers both'))
        return judged._replace(doubt=np.outer(difference, difference))

    def _settle_surprise(self, matcher: ScanMatcher, previous: ScanPoints,
                         current: ScanPoints, guess: se2.Pose, config: PipelineConfig,
                         judged: JudgedMatch) -> JudgedMatch:
        """Settle a clean map match that corrected a good prediction by far more than usual.

        The correction may be right (the robot braked) or the map's view may have its
        minimum elsewhere (:data:`.doubt.SURPRISE_FACTOR`). The previous scan, matched
        from the same prediction, is asked: when its match is clean and agrees
        (:func:`steps_agree`), or is not clean, the map's step stands. When the two
        disagree, each step is measured on both references with the same matcher-free
        surface fit (:func:`.recovery.surface_fit`, the global search's likelihood) and
        the one that fits both better is taken; on a tie (a corridor neither reference
        constrains along its axis) the map's. 5 copies with 1 mm range noise, median
        [worst]: MIT CSAIL plicp 3 silent failed steps in one copy -> none (ATE 0.53
        [1.68] -> 0.46 [0.73] m), fr079 plicp 2 silent -> none (drift 0.31 [0.47] ->
        0.29 [0.31] %), Intel nicp drift 0.92 [0.98] -> 0.55 [0.92] %; the fast logs
        unchanged (their doubted predictions take another path). Arbitrating
        ``map_disputed`` the same way was measured too: fr079 plicp then failed 9 steps
        silently in two copies.
        """
        self.events.count('map_surprised')
        against_scan = self._clean_scan_match(matcher, previous, current, guess, config)
        if against_scan is None:
            return judged
        registration, verdict = against_scan
        if steps_agree(verdict, judged.verdict, matcher.config.map_covariance_scale):
            return judged

        def fit(pose: se2.Pose) -> float:
            return sum(settling_fit(reference, current, pose)
                       for reference in (previous, judged.reference))
        if fit(verdict.pose) > fit(judged.verdict.pose):
            return self._fallback(previous, registration, verdict)
        return judged

    def _clean_scan_match(self, matcher: ScanMatcher, previous: ScanPoints,
                          current: ScanPoints, guess: se2.Pose, config: PipelineConfig
                          ) -> tuple[Registration, MatchVerdict] | None:
        """Return the previous scan's match from a trusted ``guess`` if clean, else None.

        The match passed the checks of a match from a prediction
        (:meth:`.Registrar.try_local`) and is judged clean (:func:`clean_match`).
        """
        registration, passed = self.scan_registrar.try_local(matcher, previous, current,
                                                             guess, config)
        if not passed:
            return None
        verdict = judge_match(registration, guess, config, current.length_scale)
        return (registration, verdict) if clean_match(registration, verdict) else None

    def _register_untrusted(self, matcher: ScanMatcher, registrar: Registrar,
                            view: ScanPoints, previous: ScanPoints, current: ScanPoints,
                            guess: se2.Pose, config: PipelineConfig,
                            untrusted: str) -> JudgedMatch:
        """Find a step without a trusted prediction: the previous scan finds, the map refines.

        ``untrusted`` names why the prediction is not trusted; '' for a trusted one
        whose map match cannot stand (:meth:`_register_doubted`), which the previous
        scan's registrar checks as in scan mode.

        The full registration (the global search and its refinement) runs against the
        previous scan. A clean result (:func:`clean_match`) is refined against the
        map's ``view`` from there (:meth:`.Registrar.refine`); the refined match
        stands when it passes the usual checks of a match from a prediction, is clean
        too and agrees with the found step within their covariances
        (:func:`steps_agree`), else the previous scan's. A degenerate or ambiguous
        result stands as it is, with the covariance that says so: refined on the map,
        such a step slid along a corridor's axis, or was judged clean at a wrong pose
        (intel's keyframes). Only a rejected result lets the map's own global search
        run, and its result stands when judged better (:func:`match_rank`). Searching
        the map from afar found wrong poses that it judged clean: on intel's keyframes
        a wrong turn of 120 deg against a correct but degenerate match.
        """
        scale = current.length_scale
        found = self.scan_registrar.register(matcher, previous, current, guess, config,
                                             untrusted)
        found_verdict = judge_match(found, guess, config, scale)
        if found_verdict.status != 'rejected':
            if clean_match(found, found_verdict):
                refined = registrar.refine(matcher, view, current, found, config)
                if refined is not None:
                    verdict = judge_match(refined, guess, config, scale)
                    if clean_match(refined, verdict) and steps_agree(
                            found_verdict, verdict, matcher.config.map_covariance_scale):
                        return JudgedMatch(view, registrar, refined, verdict, found=found)
            return self._fallback(previous, found, found_verdict)
        searched = registrar.register(matcher, view, current, guess, config, untrusted)
        verdict = judge_match(searched, guess, config, scale)
        if match_rank(searched, verdict) > match_rank(found, found_verdict):
            return JudgedMatch(view, registrar, searched, verdict)
        return self._fallback(previous, found, found_verdict)

    def expect(self, carried: np.ndarray) -> None:
        """Tell the previous scan's registrar what the next trusted guess carries.

        :meth:`.Registrar.expect`; the pipeline tells the map's registrar itself.
        """
        self.scan_registrar.expect(carried)

    def update(self, current: ScanPoints, pose: se2.Pose, judged: JudgedMatch,
               registrar: Registrar, stamp_ns: int) -> None:
        """Let a trusted scan join the map at ``pose``; restart the map after a rejection.

        A match against the map that was accepted, not ambiguous, and leaves a residual
        about as small as usual (:func:`.local_map.reference.fits_usual`) places the
        scan well enough to build on (a degenerate one too: its weak direction took the
        prediction, and the map, featureless along it, stays consistent). How much of
        the scan the map covered is no test: a scan that sees new ground pairs fewer
        points, and must join for the map to grow there (held to the usual share, such
        scans were refused five in a row and restarted the map: fr079 nicp 147 times,
        1 mm of range noise moving the ATE 0.33 -> 0.81 m). A rejected match restarts
        the map from the current scan at the pose the pipeline took.
        """
        if judged.verdict.status == 'rejected':
            self.map.restart(current, pose)
            self.events.count('map_restarted')
            return
        # The step is known: the registrar that did not make it has not lost track.
        # A step found against the previous scan and refined against the map was
        # that registrar's match too: it joins its history as in scan-to-scan mode.
        if judged.found is not None:
            self.scan_registrar.accepted(judged.found.match)
        else:
            (self.scan_registrar if judged.from_map else registrar).settled()
        fits = (judged.from_map and not judged.registration.alternatives
                and fits_usual(judged.registration.match,
                               judged.registrar.usual.residual(), None))
        if self.map.offer(current, pose, fits) == 'restarted':
            self.events.warn('map_restarted', f'the local map restarted at '
                             f't={stamp_ns * 1e-9:.3f}: {MAX_REFUSED} scans in a row fitted '
                             'it poorly (the scene changed, or the map went wrong)')

    def _fallback(self, previous: ScanPoints, registration: Registration,
                  verdict: MatchVerdict) -> JudgedMatch:
        """Return a match against the previous scan, counted as ``map_fallback``."""
        self.events.count('map_fallback')
        return JudgedMatch(previous, self.scan_registrar, registration, verdict, False)
