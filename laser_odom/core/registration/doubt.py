"""When a trusted prediction is only a hypothesis: the match from it is checked by the search.

A trusted prediction (the constant-velocity step after an accepted match) seeds the
matcher, and the match from it is taken when it converged, paired as usual and stayed
within ``max_correction_*`` of it (:mod:`laser_odom.core.registration.rejection`). That
is right when the prediction is good to a fraction of the matcher's basin. When it is
not, a match that converged to a wrong minimum passes those checks and is judged clean:
a robot 5-10x faster than the logs' (their every 5th or 10th scan, 0.1 s apart) had
twice the failed steps of ``prior: none``, most of them silent, on intel's keyframes.

So the prediction is doubted, and the match from it competes with the global search's
refined poses (:mod:`laser_odom.core.registration.recovery`, chosen by the surface fit,
poses that fit alike reported as ambiguous), when

* the predicted step is as large as the correction gate (``max_correction_*``): a robot
  that stops, or turns the other way, then lies beyond what the match from the
  prediction may correct - its failure could not even be detected;
* or fewer than :data:`MIN_RECORD` trusted matches since the last untrusted one
  showed how well it predicts;
* or the prediction missed by more than :data:`MISS_FRACTION` of that gate on one of
  the last :data:`RECENT_MISSES` trusted matches: the motion is changing faster than
  the constant velocity follows;
* or the match from one of the last :data:`RECENT_MISSES` trusted predictions slid
  beyond that gate (:data:`SLID`): the matcher's basin, not the prediction, failed
  there, and the next match from as good a prediction can slide less far and pass
  (the simulated fast hall, plicp: the search found the step within 2 cm of the
  prediction; the next match from a prediction as good slid 0.25 m back along the
  aisle, was taken as ``matched`` and, de-skewed with its own motion and matched
  again, 0.45 m: 0.65 m off with a 2 cm deviation, and the constant velocity carried
  it silently over four more steps);
* or the match from it corrected it by far more than the recent misses
  (:meth:`PredictionDoubt.would_surprise`): where the scene barely constrains a
  direction, a match can slide to a minimum elsewhere along it from a prediction good
  to a centimetre (the simulated campus, plicp: 0.3 m back between two long walls, and
  the constant velocity carried the slide on through the next degenerate steps).

At full rate neither holds but for a few scans (fr079, mit-csail, intel: predictions
off by a few centimetres and degrees), so the search's cost is paid where it is needed.
"""

from __future__ import annotations

from collections import deque
import math
from typing import Iterable

import numpy as np

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import AcceptanceConfig

RECENT_MISSES = 10
"""Trusted matches whose prediction errors are remembered."""

MIN_RECORD = 3
"""A prediction is doubted until this many trusted matches since the last untrusted
one (a start, a gap, a rejection) showed how well it predicts: the first is the step
of one match extrapolated (fr079 every 10th scan at 10 Hz: 1.35 m off, silent)."""

MISS_FRACTION = 0.5
"""A prediction that missed by this fraction of ``max_correction_*`` (0.25 m or
14 deg by default) came near the edge of the matcher's basin: the next ones are
checked. At full rate the constant velocity misses by at most 0.32 m / 24 deg (fr079,
plicp; 99 % of the last-ten maxima below 0.19 m / 14 deg), so few scans are checked;
on the fast logs it misses by more than that in nine of ten windows."""

SLID = 'large_correction'
"""The local failure (:func:`.rejection.rejection_reason`) of a match that slid beyond
``max_correction_*`` from its trusted prediction."""

SURPRISE_FACTOR = 3.0
"""A trusted prediction corrected by more than this multiple of the largest of the
recent misses before it (in translation or rotation) surprised the match: a map whose
view has its minimum elsewhere (MIT CSAIL, plicp: 0.25 m back along a corridor from a
prediction the previous scan confirmed to 1 cm; then 0.21 m, and the constant velocity
carried the wrong steps on for 9 scans, 2.8 m, silently). Over fr079, MIT CSAIL and
Intel (plicp, nicp, imls, 5 copies with 1 mm range noise) 3 left 2 failed steps, 4 left
5 (fr079 plicp's silent ones stayed) and 2 left 2 with more drift on fr079; the fast
logs are the same with any of them (their predictions are doubted first)."""

SURPRISE_FLOOR = (0.02, 0.02)
"""The recent misses [m, rad] counted as at least this: predictions that hit to a
millimetre do not make a centimetre's correction a surprise."""


def missed_far(linear: float, angular: float, config: AcceptanceConfig) -> bool:
    """Tell whether a prediction's miss [m, rad] exceeds :data:`MISS_FRACTION` of the gate."""
    return bool(linear > MISS_FRACTION * config.max_correction_linear
                or angular > MISS_FRACTION * config.max_correction_angular)


class PredictionDoubt:
    """How far recent trusted predictions were from the steps matched: whether to doubt."""

    def __init__(self) -> None:
        """Start with no misses recorded."""
        self._misses: deque[tuple[float, float]] = deque(maxlen=RECENT_MISSES)
        self._slid: deque[bool] = deque(maxlen=RECENT_MISSES)
        """Whether the match from each recorded prediction slid beyond the gate."""

    def clear(self) -> None:
        """Forget the recent misses."""
        self._misses.clear()
        self._slid.clear()

    def record(self, guess: se2.Pose, pose: se2.Pose,
               alternatives: Iterable[np.ndarray] = (), local_failure: str = '') -> None:
        """Record how far a trusted prediction ``guess`` was from the step matched.

        ``local_failure`` is why the match from ``guess`` failed before the search
        found the step ('' when it did not): :data:`SLID` keeps the next predictions
        in doubt however near the step was found.

        A step chosen among ``alternatives`` that fit alike (taken nearest the
        prediction) does not confirm the prediction: it may have missed by as much as
        the farthest of them. Counted so, a prediction that led to an alias of a
        repetitive scene stays in doubt, instead of being confirmed by its own choice
        (a corridor of pillars 1.2 m apart, driven at 1.1 m per scan: every later step
        was a silent alias).
        """
        missed = _largest_miss(guess, [other for other in [pose, *alternatives]
                                       if se2.is_finite_pose(other)])
        if missed is not None:
            self._misses.append((float(missed[0]), float(missed[1])))
            self._slid.append(local_failure == SLID)

    def unproven(self) -> bool:
        """Tell whether fewer than :data:`MIN_RECORD` trusted matches are on record."""
        return len(self._misses) < MIN_RECORD

    def surprised(self) -> bool:
        """Tell whether the newest miss is far beyond the recent ones before it.

        The newest record is the match just made; the records before it set the scale
        (:data:`SURPRISE_FACTOR`, :data:`SURPRISE_FLOOR`). Unlike :meth:`doubt`, which
        checks the next predictions after a large miss, this questions the match that
        made it. With fewer than :data:`MIN_RECORD` before it (after a start, a gap or
        a search) the prediction is not proven, and what they show is floored as
        always: a correction of more than a few centimetres or degrees surprises.
        Waiting for a full record let a match slide where the record had just been
        cleared: fr079 as received, plicp against the map, two scans after a gap, a
        robot at rest, the map's match from a prediction of rest turned 14.2 deg in 177
        iterations, just short of the miss that has the search check an unproven
        prediction (:func:`.map_judging.overshot_unproven`), and was published with a
        deviation of 0.3 deg; it and the way back were 2 silent failed steps. 10 copies
        with 1 mm range noise, median [worst] 50 m drift: fr079 plicp 0.31 [0.35] ->
        0.30 [0.35] % (1 silent failed step -> none), Intel plicp 0.83 [2.66] -> 0.65
        [2.66] %, fr079 imls 0.29 [0.38] -> 0.28 [0.45] %; MIT CSAIL plicp's ATE (5
        copies) 0.54 [0.57] -> 0.49 [0.56] m; nicp, MIT CSAIL's other rows and the
        fast-robot logs unchanged.
        """
        if not self._misses:
            return False
        *earlier, newest = self._misses
        return _beyond(np.array(newest), earlier) is not None

    def would_surprise(self, guess: se2.Pose, pose: se2.Pose) -> str:
        """Return why the match ``pose`` from ``guess`` surprises, '' if it does not.

        :meth:`surprised` for a match not yet recorded (the scan-to-scan registrar
        asks before it takes the match): its miss against the :data:`MIN_RECORD` or
        more recent ones.
        """
        if len(self._misses) < MIN_RECORD:
            return ''
        newest = _largest_miss(guess, [pose])
        usual = _beyond(newest, list(self._misses))
        if usual is None:
            return ''
        return (f'the match corrected the prediction by {newest[0]:.2f} m / '
                f'{math.degrees(newest[1]):.1f} deg, recent ones by up to {usual[0]:.2f} m '
                f'/ {math.degrees(usual[1]):.1f} deg')

    def doubt(self, guess: se2.Pose, config: AcceptanceConfig, unproven: bool = True) -> str:
        """Return why the match from ``guess`` must be checked by the search, '' if not.

        ``unproven=False`` leaves out the doubt of a prediction with too short a record
        (:data:`MIN_RECORD`): for a registrar that matches only now and then (the
        previous scan's second opinion against a local map), whose record stays short.
        """
        linear = float(np.hypot(guess[0], guess[1]))
        angular = abs(float(se2.wrap_angle(guess[2])))
        if linear >= config.max_correction_linear or angular >= config.max_correction_angular:
            return (f'a predicted step of {linear:.2f} m / {np.degrees(angular):.1f} deg, '
                    'beyond the correction gate: a stop would pass unseen')
        if unproven and self.unproven():
            return f'{len(self._misses)} trusted predictions since the last search'
        if any(self._slid):
            return 'the match from a recent prediction slid beyond the correction gate'
        if self._misses:
            missed = np.max(np.array(self._misses), axis=0)
            if missed_far(missed[0], missed[1], config):
                return (f'recent predictions missed by up to {missed[0]:.2f} m / '
                        f'{np.degrees(missed[1]):.1f} deg')
        return ''


def _largest_miss(guess: se2.Pose, poses: list[np.ndarray]) -> np.ndarray | None:
    """Return the largest distance [m] and turn [rad] from ``guess`` to ``poses``."""
    if not poses:
        return None
    missed = np.array([se2.relative(guess, pose) for pose in poses])
    return np.array([np.max(np.hypot(missed[:, 0], missed[:, 1])),
                     np.max(np.abs(se2.wrap_angle(missed[:, 2])))])


def _beyond(newest: np.ndarray, earlier: list[tuple[float, float]]) -> np.ndarray | None:
    """Return the usual misses [m, rad] that ``newest`` exceeds by :data:`SURPRISE_FACTOR`.

    The usual miss is the largest of ``earlier`` (none: nothing), floored at
    :data:`SURPRISE_FLOOR`; None when ``newest`` is within the factor of it in both
    translation and rotation.
    """
    usual = np.array(SURPRISE_FLOOR, dtype=float)
    if earlier:
        usual = np.maximum(np.max(np.array(earlier), axis=0), usual)
    return usual if np.any(newest > SURPRISE_FACTOR * usual) else None
