"""Where the scan is blind, a prediction with a measured error stands in.

:class:`StepHistory` measures how well a constant-velocity step predicts the next one
from consecutive well-constrained steps; :func:`judge_match` puts the prediction (the
trusted guess, or with ``prior: none`` the last well-constrained step's translation at
a steady rate) along the directions a match does not constrain, with that error as
the variance, and says so.
"""

import math

import numpy as np

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import PipelineConfig
from laser_odom.core.matchers import MatchResult
from laser_odom.core.motion.blind_prior import (
    MIN_HISTORY, Prediction, PREDICTION_FLOOR, StepHistory, UNPREDICTED_HEADING)
from laser_odom.core.registration.acceptance import DEGENERATE_VARIANCE, judge_match
from laser_odom.core.registration.registrar import Registration

SECOND = 1_000_000_000


def steady(history: StepHistory, steps, start: int = 0, interval: int = SECOND) -> int:
    """Add well-constrained steps one ``interval`` apart; return the last stamp."""
    stamp = start
    for step in steps:
        history.add(stamp, stamp + interval, np.array(step, dtype=float), True)
        stamp += interval
    return stamp


def test_the_prediction_error_is_the_spread_of_consecutive_velocity_changes():
    history = StepHistory()
    steps = [(1.0, 0.0, 0.0), (1.1, 0.0, 0.02), (0.9, 0.1, 0.0), (1.0, 0.0, 0.0),
             (1.2, -0.1, 0.02)]
    end = steady(history, steps)
    changes = np.diff(np.array(steps), axis=0)  # 1 s intervals: velocity changes
    expected = np.maximum(np.mean(np.square(changes), axis=0), PREDICTION_FLOOR)
    np.testing.assert_allclose(np.diag(history.covariance(1.0)), expected, rtol=1e-12)
    # Over 2 s the same velocity changes err twice as far.
    np.testing.assert_allclose(np.diag(history.covariance(2.0)),
                               np.maximum(4.0 * np.mean(np.square(changes), axis=0),
                                          PREDICTION_FLOOR), rtol=1e-12)
    prediction = history.last_step(end, end + SECOND)
    np.testing.assert_allclose(prediction.pose, steps[-1])
    assert prediction.source == 'last_step'
    assert prediction.covariance[2, 2] == UNPREDICTED_HEADING  # the turn is not predicted


def test_no_prediction_without_history_a_steady_rate_or_the_last_scan_as_reference():
    history = StepHistory()
    end = steady(history, [(1.0, 0.0, 0.0)] * MIN_HISTORY)  # MIN_HISTORY - 1 changes
    assert history.covariance(1.0) is None and history.last_step(end, end + SECOND) is None
    end = steady(history, [(1.0, 0.0, 0.0)], start=end)
    assert history.last_step(end, end + SECOND) is not None
    # 1.3 s after 1 s steps is not a steady rate; 1.2 s is.
    assert history.last_step(end, end + 1_300_000_000) is None
    scaled = history.last_step(end, end + 1_200_000_000)
    np.testing.assert_allclose(scaled.pose, [1.2, 0.0, 0.0])
    # A reference that is not the scan the last step ended at (a keyframe, a rejection).
    assert history.last_step(end - SECOND, end + SECOND) is None


def test_steps_that_were_not_well_constrained_widen_the_last_steps_prediction():
    history = StepHistory()
    end = steady(history, [(1.0, 0.0, 0.0), (1.1, 0.0, 0.0)] * 3)
    single = history.last_step(end, end + SECOND).covariance
    before = history.covariance(1.0)
    for _ in range(2):  # two blind steps along a corridor
        history.add(end, end + SECOND, np.array([1.0, 0.0, 0.0]), False)
        end += SECOND
    prediction = history.last_step(end, end + SECOND)
    np.testing.assert_allclose(prediction.pose, [1.1, 0.0, 0.0])  # the last good one
    np.testing.assert_allclose(prediction.covariance[:2, :2], 3.0 * single[:2, :2])
    # A blind step breaks the chain of consecutive changes: the next good step's
    # velocity is not compared with the one before the blind stretch.
    history.add(end, end + SECOND, np.array([3.0, 0.0, 0.0]), True)
    np.testing.assert_allclose(history.covariance(1.0), before)


def corridor_match(correction: float) -> MatchResult:
    """Return a match that constrains y and heading but not x (a corridor along x)."""
    information = np.diag([1.0, 1e6, 1e6])
    return MatchResult(pose=se2.pose(correction, 0.01, 0.002), converged=True,
                       iterations=5, inlier_ratio=0.9, residual=0.01,
                       information=information, covariance=np.linalg.inv(information))


def test_along_a_blind_direction_the_prediction_and_its_error_stand_in():
    config = PipelineConfig()
    prediction = Prediction(se2.pose(0.95, 0.0, 0.0), np.diag([4e-4, 4e-4, 1e-4]), 'prior')
    guess = prediction.pose
    match = corridor_match(0.8)  # 0.15 m short of the guess: inside the gates
    verdict = judge_match(Registration(match, prediction=prediction), guess, config, 2.0)
    assert verdict.status == 'degenerate' and match.extra['predicted'] == 'prior'
    np.testing.assert_allclose(verdict.pose, [0.95, 0.01, 0.002])
    assert math.isclose(verdict.covariance[0, 0], 4e-4, rel_tol=1e-9)
    assert verdict.covariance[1, 1] < 1e-5
    # Without one the axis keeps the guess and a variance of ignorance.
    bare = judge_match(Registration(corridor_match(0.8)), guess, config, 2.0)
    assert math.isclose(bare.covariance[0, 0], DEGENERATE_VARIANCE, rel_tol=1e-9)
    # The last step's turn is not predicted: it cannot replace a blind heading.
    turn_blind = MatchResult(pose=se2.pose(0.9, 0.0, 0.3), converged=True, iterations=5,
                             inlier_ratio=0.9, residual=0.01,
                             information=np.diag([1e6, 1e6, 1e-3]),
                             covariance=np.diag([1e-6, 1e-6, 1e3]))
    last = Prediction(se2.pose(0.9, 0.0, 0.0), np.diag([4e-4, 4e-4, UNPREDICTED_HEADING]),
                      'last_step')
    registration = Registration(turn_blind, trigger='no_prior', trusted=False, prediction=last)
    verdict = judge_match(registration, se2.pose(), config, 2.0)
    assert math.isclose(verdict.covariance[2, 2], DEGENERATE_VARIANCE / 4.0, rel_tol=1e-9)


def test_a_step_judged_degenerate_stays_out_of_the_measured_prediction_error():
    """A match made again after de-skewing may look clean while its step stays degenerate.

    Its velocity must not join the history as well constrained: a 1.5 m alias taken
    so made the prediction's measured error 0.35 m (the simulated fast hall, plicp).
    """
    from laser_odom.core.events import EventLog
    from laser_odom.core.registration.registrar import Registrar

    def registrar_after(status: str) -> Registrar:
        registrar = Registrar(EventLog(lambda message: None))
        for k in range(8):
            registrar._stamps = (k * SECOND, (k + 1) * SECOND)
            step = (1.5, 1.5, 0.0) if k == 7 else (1.0, 0.0, 0.0)
            tight = MatchResult(pose=np.array(step), converged=True, iterations=5,
                                inlier_ratio=0.9, residual=0.01,
                                information=np.eye(3) * 1e6, covariance=np.eye(3) * 1e-6)
            registrar.accepted(tight, status if k == 7 else 'matched')
        return registrar

    clean, degenerate = registrar_after('matched'), registrar_after('degenerate')
    assert clean.history.covariance(1.0)[1, 1] > 0.1  # the 1.5 m jump was measured
    np.testing.assert_allclose(degenerate.history.covariance(1.0), np.diag(PREDICTION_FLOOR))


def test_a_prediction_that_repeats_a_degenerate_step_carries_its_error():
    """The trusted guess's covariance adds what it carries; a degenerate match covers it.

    The match is blind along x only, but the step the guess repeats was an alias off
    across the corridor too: the verdict is at least as wide as the prediction in every
    direction. Without a carried error the match's strong directions keep their own
    variance (:func:`test_along_a_blind_direction_the_prediction_and_its_error_stand_in`).
    """
    from laser_odom.core.events import EventLog
    from laser_odom.core.registration.registrar import Registrar
    registrar = Registrar(EventLog(lambda message: None))
    end = steady(registrar.history, [(1.0, 0.0, 0.0), (1.01, 0.0, 0.0)] * 3)
    registrar.elapsed_s = 1.0
    carried = np.array([[0.01, -0.05, 0.0], [-0.05, 2.0, 0.01], [0.0, 0.01, 0.001]])
    registrar.expect(carried)
    guess = se2.pose(1.0, 0.0, 0.0)
    reference = type('Scan', (), {'stamp_ns': end})()
    prediction = registrar.predict(guess, '', reference, reference)
    assert prediction.carried and prediction.source == 'prior'
    np.testing.assert_allclose(prediction.covariance,
                               registrar.history.covariance(1.0) + carried, rtol=1e-12)
    verdict = judge_match(Registration(corridor_match(0.9), prediction=prediction), guess,
                          PipelineConfig(), 2.0)
    assert verdict.status == 'degenerate'
    difference = verdict.covariance - prediction.covariance
    assert np.linalg.eigvalsh(0.5 * (difference + difference.T)).min() > -1e-12
    registrar.expect(np.zeros((3, 3)))
    plain = registrar.predict(guess, '', reference, reference)
    assert not plain.carried
    verdict = judge_match(Registration(corridor_match(0.9), prediction=plain), guess,
                          PipelineConfig(), 2.0)
    assert verdict.covariance[1, 1] < 1e-5
