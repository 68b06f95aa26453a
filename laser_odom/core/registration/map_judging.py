"""How map mode judges a match: clean or not, how it ranks, whether two steps agree.

The local map's registration (:mod:`laser_odom.core.registration.map_registrar`) weighs
the match against the map with the previous scan's as a second opinion; these are the
tests it decides by, kept apart from the decisions themselves.
"""

from __future__ import annotations

import numpy as np

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import PipelineConfig
from laser_odom.core.matchers import MatchResult
from laser_odom.core.registration.acceptance import MatchVerdict
from laser_odom.core.registration.doubt import missed_far
from laser_odom.core.registration.registrar import Registrar, Registration
from laser_odom.core.uncertainty.pose_uncertainty import CHI2_3DOF_999, nees

STATUS_RANK = {'rejected': 0, 'degenerate': 1, 'matched': 2}
"""Order of the verdicts, worst first."""


def overshot_unproven(registrar: Registrar, local: MatchResult | None, guess: se2.Pose,
                      config: PipelineConfig) -> bool:
    """Tell whether the map's match moved far from a prediction not yet proven.

    Fewer than :data:`.doubt.MIN_RECORD` trusted matches since the last untrusted one
    back the prediction, and the match against the map from it corrected it by more
    than :data:`.doubt.MISS_FRACTION` of ``max_correction_*`` (the miss after which
    later predictions are checked): it is the prediction that is in doubt, so neither
    the map's match from it nor the previous scan's is taken unchecked; the previous
    scan searches, as in scan mode (:meth:`.MapRegistrar._register_doubted`).
    fr079 every 10th scan at 10 Hz, the second step, from a prediction of rest: with
    nicp the map's match reached the true 1.0 m, beyond the gate, and the previous
    scan's from rest, 0.33 m backwards, was published as the clean fallback; with imls
    the map's own match, 0.45 m backwards, was. At full rate (fr079, 15 copies with
    1 mm range noise) plicp's silent failed steps fell from 13 to 3; intel-kf-fast
    nicp lost its silent step too.
    """
    if not (config.search.global_search == 'recover' and local is not None
            and registrar.doubt.unproven()):
        return False
    correction = se2.relative(guess, local.pose)
    return missed_far(float(np.hypot(correction[0], correction[1])),
                      abs(float(se2.wrap_angle(correction[2]))), config.acceptance)


def clean_match(registration: Registration, verdict: MatchVerdict) -> bool:
    """Tell whether a match is accepted with nothing to doubt.

    Matched (not degenerate, not rejected), and neither the match from the prediction
    failed nor did another pose fit alike.
    """
    return (verdict.status == 'matched' and not registration.local_failure
            and not registration.alternatives)


def match_rank(registration: Registration, verdict: MatchVerdict) -> tuple[int, bool]:
    """Return how good a judged match is: its status, then whether it is clean."""
    return STATUS_RANK[verdict.status], clean_match(registration, verdict)


def steps_agree(found: MatchVerdict, refined: MatchVerdict, map_scale: float) -> bool:
    """Tell whether a step refined on the map agrees with the step found against the scan.

    Both measure the same step; their difference ``d`` is weighed by the sum of their
    published covariances (the map's scaled by ``map_covariance_scale``, as
    :func:`.pose_uncertainty.step_error` publishes it): ``d^T (P1 + P2)^-1 d``
    (:func:`.pose_uncertainty.nees`) within the 99.9 % chi-square bound. The two share
    the current scan's noise, so the test is lenient. A refinement that moved a clean
    match by more slid into another minimum of the map (measured on intel's keyframes:
    0.5 m along a corridor, silently).
    """
    covariance = np.asarray(found.covariance) + map_scale * np.asarray(refined.covariance)
    try:
        return nees(np.asarray(refined.pose) - found.pose, covariance) <= CHI2_3DOF_999
    except np.linalg.LinAlgError:
        return False
