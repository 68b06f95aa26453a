"""The odometry pipeline: prediction, integration, stamps, keyframes, acceptance."""

import math

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.core.config import PipelineConfig
from laser_odom.core.metrics import evaluate
from laser_odom.core.pipeline import OdometryPipeline
from laser_odom.core.runner import run_pipeline
from laser_odom.core.scan import LaserScan
from laser_odom.core.simulation import simulate


@pytest.fixture(scope='module')
def office_run():
    """Twenty seconds in the office world: 200 scans with ground truth."""
    return simulate('office', duration=20.0, seed=3)


def replace_stamp(scan: LaserScan, stamp_ns: int) -> LaserScan:
    return LaserScan(stamp_ns, scan.angle_min, scan.angle_max, scan.angle_increment,
                     scan.range_min, scan.range_max, scan.ranges, scan.intensities,
                     scan.frame_id)


def motion_model(prior: str = 'constant_velocity', max_scan_gap: float = 1.0):
    from laser_odom.core.config import MotionConfig
    from laser_odom.core.motion import MotionModel
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
    for prior in ('odom', 'imu'):
        model = motion_model(prior)
        model.velocity = velocity.copy()
        counters = Counter()
        for missing_step, missing_yaw in ((None, None), (se2.pose(math.nan), math.nan)):
            predicted = model.predict(0.1, missing_step, missing_yaw, counters)
            np.testing.assert_allclose(predicted, [0.05, -0.02, 0.03], atol=1e-12)
        assert counters['prior_missing'] == 2, prior
        np.testing.assert_allclose(model.predict(0.1), [0.05, -0.02, 0.03], atol=1e-12)
        assert counters['prior_missing'] == 2  # no counters given: nothing counted


def test_motion_model_predicts_nothing_over_a_gap_longer_than_max_scan_gap():
    """A gap of exactly max_scan_gap is still predicted; a longer one is not."""
    for prior in ('constant_velocity', 'odom', 'imu'):
        model = motion_model(prior, max_scan_gap=0.5)
        model.velocity = np.array([1.0, 0.0, 0.2])
        assert not model.gap_exceeded(0.5) and model.gap_exceeded(0.5 + 1e-9)
        np.testing.assert_allclose(model.predict(0.5, se2.pose(0.5, 0.0, 0.1), 0.1),
                                   [0.5, 0.0, 0.1], atol=1e-12)
        np.testing.assert_array_equal(
            model.predict(0.5 + 1e-9, se2.pose(0.5, 0.0, 0.1), 0.1), [0.0, 0.0, 0.0])


def test_motion_model_velocity_is_the_step_over_its_interval():
    """Velocity = step / dt; a gap, dt <= 0 or a non-finite step stop it; dt < 5 ms keeps it.

    An interval of exactly MIN_VELOCITY_DT or max_scan_gap still gives a velocity.
    """
    from laser_odom.core.motion import MIN_VELOCITY_DT
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
    """From five recorded intervals on, one under half the median is taken as the median.

    Non-positive intervals are not recorded; the period covers the last PERIOD_WINDOW.
    """
    from laser_odom.core.motion import PERIOD_WINDOW
    model = motion_model()
    for _ in range(4):
        model.update(se2.pose(), 0.1)
    model.update(se2.pose(), -0.05)
    model.update(se2.pose(), 0.0)
    assert model.effective_dt(0.01) == 0.01  # four intervals: no period yet
    model.update(se2.pose(), 0.1)
    assert model.effective_dt(0.01) == 0.1
    assert model.effective_dt(0.05) == 0.05  # half the median is not short
    assert model.effective_dt(0.3) == 0.3
    model.forget_intervals()
    assert model.effective_dt(0.01) == 0.01
    window = motion_model()
    for dt in [0.9] + [0.2] * (PERIOD_WINDOW - 5) + [0.01] * 5:  # bursty: the mean is used
        window.update(se2.pose(), dt)
    # Only the last 25 intervals count (a window of 26 would give 0.19, one of 24 0.1604).
    assert window.effective_dt(0.2) == pytest.approx((20 * 0.2 + 5 * 0.01) / 25, rel=1e-12)


def test_motion_model_bursty_stamps_are_those_with_over_a_tenth_of_short_intervals():
    """Over JITTER_FRACTION of intervals below half the median: the mean interval is used."""
    from laser_odom.core.motion import JITTER_FRACTION
    assert JITTER_FRACTION == 0.1
    cases = (([0.2] * 20 + [0.01] * 5, (20 * 0.2 + 5 * 0.01) / 25),  # 20 % short: bursty
             ([0.2] * 18 + [0.01] * 2, 0.2),  # exactly 10 % short: regular
             ([0.2] * 20 + [0.1] * 5, 0.2))  # exactly half the median is not short
    for intervals, expected in cases:
        model = motion_model()
        for dt in intervals:
            model.update(se2.pose(), dt)
        assert model.effective_dt(0.2) == pytest.approx(expected, rel=1e-12)
        assert model.effective_dt(0.01) == pytest.approx(expected, rel=1e-12)


def test_tracks_ground_truth_and_reports_finite_spd_covariance(office_run):
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    result = run_pipeline(pipeline, office_run.scans)
    assert result.processed == len(office_run.scans)
    errors = evaluate(result.trajectory, office_run.reference)
    assert errors.ate_rms < 0.05
    assert errors.rpe_trans_mean < 0.005
    for covariance in result.pose_covariances[1:]:
        assert np.all(np.isfinite(covariance))
        assert np.allclose(covariance, covariance.T)
        assert np.all(np.linalg.eigvalsh(covariance) > 0.0)
    # Pose uncertainty grows as the odometry integrates.
    assert np.trace(result.pose_covariances[-1]) > np.trace(result.pose_covariances[10])


def test_twist_is_in_the_base_frame(office_run):
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    estimates = [pipeline.process(scan) for scan in office_run.scans[:30]]
    truth = office_run.reference.poses
    dt = (office_run.scans[29].stamp_ns - office_run.scans[28].stamp_ns) * 1e-9
    expected = se2.relative(truth[28], truth[29]) / dt
    assert np.allclose(estimates[29].twist, expected, atol=0.05)
    assert estimates[29].twist_covariance.shape == (3, 3)


def test_constant_velocity_prediction_is_the_initial_guess(office_run):
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    for scan in office_run.scans[:10]:
        pipeline.process(scan)
    velocity = pipeline.motion.velocity
    assert np.allclose(pipeline.motion.predict(0.1), velocity * 0.1)
    none = OdometryPipeline(PipelineConfig(matcher='icp'))
    none.config.motion.prior = 'none'
    assert np.allclose(none.motion.predict(0.1), 0.0)


def test_duplicate_stamp_is_skipped_and_time_jump_back_resets(office_run):
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    scans = office_run.scans
    for scan in scans[:20]:
        pipeline.process(scan)
    assert pipeline.process(scans[19]) is None
    assert pipeline.counters['duplicate_stamp'] == 1
    moved = pipeline.pose.copy()
    assert np.hypot(moved[0], moved[1]) > 0.2
    restarted = pipeline.process(scans[0])
    assert restarted.status == 'initialized'
    assert pipeline.counters['time_jump_back'] == 1
    assert np.allclose(restarted.pose, 0.0)


def test_scan_gap_drops_the_prior(office_run):
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    for scan in office_run.scans[:10]:
        pipeline.process(scan)
    late = replace_stamp(office_run.scans[10], office_run.scans[9].stamp_ns + int(5e9))
    pipeline.process(late)
    assert pipeline.counters['scan_gap'] == 1


def test_keyframes_hold_the_reference_while_the_robot_stands_still(office_run):
    config = PipelineConfig(matcher='icp')
    config.keyframes.keyframe_distance = 0.5
    config.keyframes.keyframe_angle = math.radians(20.0)
    pipeline = OdometryPipeline(config)
    first = office_run.scans[0]
    pipeline.process(first)
    keyframe = pipeline.keyframe
    rng = np.random.default_rng(0)
    for k in range(1, 50):
        ranges = first.ranges + rng.normal(0.0, 0.01, first.ranges.shape)
        still = LaserScan(first.stamp_ns + k * 100_000_000, first.angle_min,
                          first.angle_max, first.angle_increment, first.range_min,
                          first.range_max, ranges)
        estimate = pipeline.process(still)
    assert pipeline.keyframe is keyframe
    # Matching against one keyframe does not random-walk: the error stays at one match's.
    assert np.hypot(*estimate.pose[:2]) < 0.005


def test_rejected_match_advances_by_the_prediction(office_run):
    config = PipelineConfig(matcher='icp')
    config.acceptance.max_correction_linear = 1e-9  # no match lands exactly on the guess
    config.search.global_search = 'off'  # nothing checks the match again
    pipeline = OdometryPipeline(config)
    pipeline.process(office_run.scans[0])
    pipeline.motion.velocity = np.array([0.5, 0.0, 0.0])
    estimate = pipeline.process(office_run.scans[1])
    assert estimate.status == 'rejected'
    assert np.allclose(estimate.pose, [0.05, 0.0, 0.0])
    assert estimate.pose_covariance[0, 0] >= 0.25


def test_jittery_logger_stamps_use_the_mean_scan_interval():
    from laser_odom.core.config import MotionConfig
    from laser_odom.core.motion import MotionModel
    model = MotionModel(MotionConfig())
    bursty = [0.01, 0.39] * 10  # a 5 Hz sensor logged in pairs
    for dt in bursty:
        model.update(np.array([0.1, 0.0, 0.05]), dt)
    assert abs(model.effective_dt(0.01) - 0.2) < 1e-9
    assert np.allclose(model.predict(0.39), [0.1, 0.0, 0.05])
    regular = MotionModel(MotionConfig())
    for dt in [0.1] * 10 + [0.2]:  # true stamps with one dropped scan
        regular.update(np.array([0.05, 0.0, 0.0]), dt)
    assert regular.effective_dt(0.2) == 0.2
    assert regular.effective_dt(0.001) == 0.1  # a lone glitch is one period


def test_acceptance_rejects_unconverged_and_poorly_paired_matches():
    from laser_odom.core.acceptance import rejection_reason
    from laser_odom.core.config import AcceptanceConfig
    from laser_odom.core.matchers import MatchResult
    guess = se2.pose(0.1, 0.0, 0.0)
    good = MatchResult(pose=guess.copy(), converged=True, iterations=5, inlier_ratio=0.9,
                       residual=0.01, information=np.eye(3), covariance=np.eye(3) * 1e-4)
    config = AcceptanceConfig()
    assert rejection_reason(good, guess, config) is None
    unconverged = MatchResult(**{**good.__dict__, 'converged': False})
    assert rejection_reason(unconverged, guess, config) == 'not_converged'
    sparse = MatchResult(**{**good.__dict__, 'inlier_ratio': config.min_inlier_ratio - 0.01})
    assert rejection_reason(sparse, guess, config) == 'low_inlier_ratio'
    assert rejection_reason(MatchResult(**{**good.__dict__, 'inlier_ratio':
                                           config.min_inlier_ratio}), guess, config) is None


@pytest.mark.parametrize('matcher', ['icp', 'plicp', 'nicp', 'imls'])
def test_reference_preparation_after_publishing_changes_no_result(office_run, matcher):
    """The node prepares the next keyframe after publishing; the result must not depend on it."""
    scans = office_run.scans[:40]
    prepared, lazy = (OdometryPipeline(PipelineConfig(matcher=matcher)) for _ in range(2))
    prepared_run = run_pipeline(prepared, scans)  # prepares after every scan
    lazy_poses = []
    for scan in scans:
        estimate = lazy.process(scan)
        lazy_poses.append(estimate.pose)
        assert not lazy.keyframe_prepared
    np.testing.assert_array_equal(prepared_run.trajectory.poses, np.array(lazy_poses))
    assert prepared.keyframe_prepared


def test_icp_reference_work_moves_off_the_matching_path(office_run):
    """The densified reference and information normals of icp are built by prepare_next."""
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    pipeline.process(office_run.scans[0])
    keyframe = pipeline.keyframe
    assert not any(key[0] in ('icp_dense', 'normals') for key in keyframe.cache)
    assert pipeline.prepare_next() > 0.0
    assert {key[0] for key in keyframe.cache} >= {'icp_dense', 'normals'}
    assert pipeline.prepare_next() == 0.0  # once per keyframe
    times = len(pipeline.processing_times)
    pipeline.process(office_run.scans[1])
    assert pipeline.keyframe is not keyframe and not pipeline.keyframe_prepared
    assert len(pipeline.processing_times) == times + 1
