"""The motion model: each prior and its fallback, the scan gap, the velocity and scan period."""

import math

import numpy as np
import pytest

from laser_odom.core import se2


def motion_model(prior: str = 'constant_velocity', max_scan_gap: float = 1.0):
    from laser_odom.core.configuration.pipeline import MotionConfig
    from laser_odom.core.motion.model import MotionModel
    return MotionModel(MotionConfig(prior=prior, max_scan_gap=max_scan_gap))


def test_motion_model_predicts_from_the_configured_prior():
    """Each prior gives its own guess; a missing or non-finite one falls back and is counted."""
    from collections import Counter
    velocity = np.array([0.5, -0.2, 0.3])
    odom_step, yaw = se2.pose(0.04, 0.01, -0.02), 0.07
    expected = {'none': [0.0, 0.0, 0.0], 'constant_velocity': [0.05, -0.02, 0.03],
                'odom': odom_step, 'imu': [0.05, -0.02, yaw]}
    for prior, guess in expected.items():
        # The name as a parameter file gives it: equal to the literal, not the same object.
        for name in (prior, ''.join(list(prior))):
            model = motion_model(name)
            model.velocity = velocity.copy()
            counters = Counter()
            predicted = model.predict(0.1, odom_step, yaw, counters)
            assert predicted.shape == (3,)
            np.testing.assert_allclose(predicted, guess, atol=1e-12, err_msg=prior)
            assert counters['prior_missing'] == 0, prior
            assert model.guess_source == prior
    for prior in ('odom', 'imu'):
        model = motion_model(prior)
        model.velocity = velocity.copy()
        counters = Counter()
        for missing_step, missing_yaw in ((None, None), (se2.pose(math.nan), math.nan)):
            predicted = model.predict(0.1, missing_step, missing_yaw, counters)
            np.testing.assert_allclose(predicted, [0.05, -0.02, 0.03], atol=1e-12)
            assert model.guess_source == 'constant_velocity'  # it stands in
        assert counters['prior_missing'] == 2, prior
        np.testing.assert_allclose(model.predict(0.1), [0.05, -0.02, 0.03], atol=1e-12)
        assert counters['prior_missing'] == 2  # no counters given: nothing counted


def test_motion_model_predicts_nothing_over_a_gap_longer_than_max_scan_gap():
    """A gap of exactly max_scan_gap is still predicted; a longer one is not extrapolated."""
    for prior in ('constant_velocity', 'odom', 'imu'):
        model = motion_model(prior, max_scan_gap=0.5)
        model.velocity = np.array([1.0, 0.0, 0.2])
        assert not model.gap_exceeded(0.5) and model.gap_exceeded(0.5 + 1e-9)
        np.testing.assert_allclose(model.predict(0.5, se2.pose(0.5, 0.0, 0.1), 0.1),
                                   [0.5, 0.0, 0.1], atol=1e-12)
        if prior != 'odom':
            np.testing.assert_array_equal(
                model.predict(0.5 + 1e-9, se2.pose(0.5, 0.0, 0.1), 0.1), [0.0, 0.0, 0.0])
            assert model.guess_source == 'none'


def test_wheel_odometry_is_used_over_a_gap_of_any_length():
    """Issue 30.14: wheel odometry measures the motion over a gap; only extrapolation stops.

    On a log with 1.5-5 s between scans a 1 s max_scan_gap used to drop the odom prior on
    nearly every step. A missing or non-finite odometry step still falls back to nothing.
    """
    step = se2.pose(1.8, 0.1, 0.3)
    # The name as a parameter file gives it: equal to the literal, not the same object.
    for name in ('odom', ''.join(list('odom'))):
        model = motion_model(name, max_scan_gap=1.0)
        model.velocity = np.array([1.0, 0.0, 0.2])
        assert not model.gap_exceeded(4.0, step) and model.gap_exceeded(4.0)
        np.testing.assert_array_equal(model.predict(4.0, step), step)
        for missing in (None, se2.pose(math.nan)):
            assert model.gap_exceeded(4.0, missing)
            np.testing.assert_array_equal(model.predict(4.0, missing), [0.0, 0.0, 0.0])


def test_motion_model_velocity_is_the_step_over_its_interval():
    """Velocity = step / dt; a gap, dt <= 0 or a non-finite step stop it; dt < 5 ms keeps it.

    An interval of exactly MIN_VELOCITY_DT or max_scan_gap still gives a velocity.
    """
    from laser_odom.core.motion.model import MIN_VELOCITY_DT
    model = motion_model(max_scan_gap=0.5)
    np.testing.assert_array_equal(model.velocity, [0.0, 0.0, 0.0])
    step = se2.pose(0.02, 0.01, 0.004)
    model.update(step, 0.5)  # a step of exactly max_scan_gap counts
    np.testing.assert_allclose(model.velocity, step / 0.5, rtol=1e-12)
    for stop_dt, stop_step in ((0.5 + 1e-9, step), (-0.1, step), (0.0, step),
                               (0.1, se2.pose(math.inf))):
        model.update(step, 0.1)
        np.testing.assert_allclose(model.velocity, step / 0.1, rtol=1e-12)
        model.update(stop_step, stop_dt)
        np.testing.assert_array_equal(model.velocity, [0.0, 0.0, 0.0])
    fresh = motion_model()
    fresh.update(step, MIN_VELOCITY_DT)  # fewer than five intervals: dt is used as it is
    np.testing.assert_allclose(fresh.velocity, step / MIN_VELOCITY_DT, rtol=1e-12)
    fresh.update(se2.pose(1.0, 1.0, 1.0), 0.999 * MIN_VELOCITY_DT)
    np.testing.assert_allclose(fresh.velocity, step / MIN_VELOCITY_DT, rtol=1e-12)
    fresh.update(step, 2.0 * MIN_VELOCITY_DT)
    np.testing.assert_allclose(fresh.velocity, step / (2.0 * MIN_VELOCITY_DT), rtol=1e-12)
    fresh.reset()
    np.testing.assert_array_equal(fresh.predict(0.1), [0.0, 0.0, 0.0])


def test_motion_model_scan_period_from_the_last_positive_intervals():
    """From five recorded intervals on, one off a whole number of periods is rounded to one.

    To the nearest whole number of median periods, at least one.

    Non-positive intervals are not recorded; the period covers the last PERIOD_WINDOW.
    """
    from laser_odom.core.motion.model import PERIOD_WINDOW
    model = motion_model()
    for _ in range(4):
        model.update(se2.pose(), 0.1)
    model.update(se2.pose(), -0.05)
    model.update(se2.pose(), 0.0)
    assert model.effective_dt(0.01) == 0.01  # four intervals: no period yet
    model.update(se2.pose(), 0.1)
    assert model.effective_dt(0.01) == 0.1
    assert model.effective_dt(0.05) == 0.1  # half a period: off-period
    assert model.effective_dt(0.08) == 0.08  # within a quarter period of one
    assert model.effective_dt(0.14) == 0.1  # 1.4 periods: off-period
    assert model.effective_dt(0.3) == 0.3  # two scans dropped
    assert model.effective_dt(0.17) == pytest.approx(0.2)  # one dropped, stamped early
    assert model.effective_dt(0.27) == pytest.approx(0.3)  # two dropped, stamped late
    model.forget_intervals()
    assert model.effective_dt(0.01) == 0.01
    window = motion_model()
    for dt in [0.9] + [0.2] * (PERIOD_WINDOW - 5) + [0.01] * 5:  # bursty: the mean is used
        window.update(se2.pose(), dt)
    # Only the last 25 intervals count (a window of 26 would give 0.19, one of 24 0.1604).
    assert window.effective_dt(0.2) == pytest.approx((20 * 0.2 + 5 * 0.01) / 25, rel=1e-12)


def test_off_period_intervals_are_those_no_sensor_stamps():
    """A sensor's intervals are a whole number of periods, give or take a quarter."""
    from laser_odom.core.motion.model import off_period, OFF_PERIOD_TOLERANCE
    assert OFF_PERIOD_TOLERANCE == 0.25
    for ratio in (0.76, 1.0, 1.24, 1.76, 2.0, 2.24, 3.1):
        assert not off_period(ratio * 0.2, 0.2), ratio
    for ratio in (0.01, 0.49, 0.5, 0.55, 0.74, 1.26, 1.45, 1.74, 2.5):
        assert off_period(ratio * 0.2, 0.2), ratio


def test_motion_model_bursty_stamps_are_those_with_over_a_tenth_off_period():
    """Over JITTER_FRACTION of intervals off a whole number of periods: the mean is used."""
    from laser_odom.core.motion.model import JITTER_FRACTION
    assert JITTER_FRACTION == 0.1
    cases = (([0.2] * 20 + [0.01] * 5, (20 * 0.2 + 5 * 0.01) / 25),  # 20 % short: bursty
             ([0.2] * 18 + [0.01] * 2, 0.2),  # exactly 10 % off: regular
             ([0.2] * 20 + [0.11] * 5, (20 * 0.2 + 5 * 0.11) / 25),  # 0.55 periods: off
             ([0.2] * 20 + [0.29] * 5, (20 * 0.2 + 5 * 0.29) / 25),  # 1.45 periods: off
             ([0.2] * 20 + [0.4] * 3 + [0.6] * 2, 0.2))  # dropped scans are a sensor's
    for intervals, expected in cases:
        model = motion_model()
        for dt in intervals:
            model.update(se2.pose(), dt)
        assert model.effective_dt(0.2) == pytest.approx(expected, rel=1e-12)
        assert model.effective_dt(0.01) == pytest.approx(expected, rel=1e-12)


def test_a_logger_stamping_late_then_early_does_not_scale_the_prediction():
    """fr079's stamps: a period of motion in every interval, a quarter of them 0.55 or 1.45.

    Scaled by the stamps, the step after a 0.13 s interval makes a velocity 1.8 times
    the robot's, and the next prediction over 0.34 s is 2.6 steps (fr079 scan 4586).
    """
    step = np.array([0.05, 0.0, 0.04])
    model = motion_model()
    stamps = [0.235, 0.235, 0.235, 0.13, 0.34, 0.235, 0.235, 0.13] * 6
    for dt in stamps:
        model.update(step, dt)
    for dt in (0.235, 0.13, 0.34):
        np.testing.assert_allclose(model.predict(dt), step, rtol=0.12)


def test_a_velocity_from_a_step_not_well_constrained_carries_its_covariance():
    """The guess repeats the step, so it carries the step's covariance scaled by (dt/dt_k)^2.

    Nothing is carried after a well-constrained step (its error is in the measured
    prediction error), after a stop or a reset, nor by a wheel-odometry guess; an IMU
    guess carries only the translation (its yaw is measured).
    """
    from collections import Counter
    covariance = np.array([[0.04, 0.01, 0.002], [0.01, 2.0, 0.003], [0.002, 0.003, 0.01]])
    model = motion_model()
    model.update(se2.pose(0.3, 0.0, 0.1), 0.1, covariance)
    model.predict(0.2)
    np.testing.assert_allclose(model.carried_covariance(0.2), covariance * 4.0, rtol=1e-12)
    model.update(se2.pose(0.3, 0.0, 0.1), 0.1)  # well constrained
    np.testing.assert_array_equal(model.carried_covariance(0.1), np.zeros((3, 3)))
    for stop in (lambda m: m.update(se2.pose(0.3), 5.0), lambda m: m.reset()):
        model.update(se2.pose(0.3, 0.0, 0.1), 0.1, covariance)
        stop(model)
        model.predict(0.1)
        np.testing.assert_array_equal(model.carried_covariance(0.1), np.zeros((3, 3)))
    odom = motion_model('odom')
    odom.update(se2.pose(0.3, 0.0, 0.1), 0.1, covariance)
    odom.predict(0.1, se2.pose(0.3, 0.0, 0.1), None, Counter())
    np.testing.assert_array_equal(odom.carried_covariance(0.1), np.zeros((3, 3)))
    odom.predict(0.1, None, None, Counter())  # missing: the constant velocity stands in
    np.testing.assert_allclose(odom.carried_covariance(0.1), covariance, rtol=1e-12)
    imu = motion_model('imu')
    imu.update(se2.pose(0.3, 0.0, 0.1), 0.1, covariance)
    imu.predict(0.1, None, 0.05, Counter())
    expected = covariance.copy()
    expected[2, :] = expected[:, 2] = 0.0
    np.testing.assert_allclose(imu.carried_covariance(0.1), expected, rtol=1e-12)


def test_a_step_weighed_against_the_prediction_keeps_what_each_knows_best():
    """The Kalman update: the well-measured coordinates follow the step, the rest stay.

    Along x the scan measured nothing (a metre of deviation against the prediction's
    2 cm): the prediction stays. Across (y) it measured to a millimetre: the step
    stands. Equal errors (the heading) meet half way, and the result's error is the
    two combined, ``(P^-1 + S^-1)^-1``.
    """
    from laser_odom.core.motion.model import fused_with_prediction
    guess, measured = se2.pose(0.2, 0.0, 0.1), se2.pose(-1.3, 0.05, 0.14)
    prior = np.diag([0.02, 0.02, 0.01]) ** 2
    step = np.diag([1.0, 0.001, 0.01]) ** 2
    fused, covariance = fused_with_prediction(guess, prior, measured, step)
    assert abs(fused[0] - 0.2) < 0.001 and abs(fused[1] - 0.05) < 0.0002, fused
    assert fused[2] == pytest.approx(0.12)
    np.testing.assert_allclose(covariance, np.linalg.inv(np.linalg.inv(prior)
                                                         + np.linalg.inv(step)), rtol=1e-9)
    # Across the angle's wrap: the innovation is the short way round.
    fused, _ = fused_with_prediction(se2.pose(0.0, 0.0, math.pi - 0.01), prior,
                                     se2.pose(0.0, 0.0, -math.pi + 0.01), prior)
    assert abs(se2.wrap_angle(fused[2] - math.pi)) < 1e-9, fused
