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


def test_counters_count_each_outcome_once(office_run):
    """scans_in counts every scan, processed the non-skipped, and each status its own."""
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    scans = office_run.scans
    for scan in scans[:12] + [scans[11]]:  # the last one repeats a stamp: skipped
        pipeline.process(scan)
    counters = pipeline.counters
    assert counters['scans_in'] == 13 and counters['processed'] == 12
    assert counters['initialized'] == 1 and counters['matched'] == 11
    assert counters['duplicate_stamp'] == 1
    assert len(pipeline.processing_times) == 12


def test_skips_and_gaps_are_said_with_the_scans_stamp(office_run):
    """The duplicate-stamp and scan-gap messages name the stamp in seconds."""
    from laser_odom.core.events import EventLog
    said = []
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'), events=EventLog(said.append))
    scans = office_run.scans
    for scan in scans[:3] + [scans[2]]:
        pipeline.process(scan)
    late = replace_stamp(scans[3], scans[2].stamp_ns + 2_500_000_000)
    pipeline.process(late)
    t2, t3 = scans[2].stamp_ns * 1e-9, late.stamp_ns * 1e-9
    assert said[0] == f'scan at t={t2:.3f} skipped: same stamp as the previous scan'
    assert said[1].startswith(f'2.50 s between the scans before t={t3:.3f}, longer than '
                              'max_scan_gap (1 s)')


def test_velocity_and_trust_follow_the_last_match(office_run):
    """After a match the velocity is the matched step over dt and the prediction trusted."""
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    estimates = [pipeline.process(scan) for scan in office_run.scans[:15]]
    truth = office_run.reference.poses
    assert estimates[-1].status == 'matched' and pipeline.untrusted == ''
    step = se2.relative(estimates[-2].pose, estimates[-1].pose)
    np.testing.assert_allclose(pipeline.motion.velocity, step / 0.1, rtol=1e-9)
    # One match is good to a few millimetres: the velocity to a few cm/s.
    np.testing.assert_allclose(pipeline.motion.velocity,
                               se2.relative(truth[13], truth[14]) / 0.1, atol=0.06)


def test_twist_covariance_is_the_step_covariance_over_dt_squared(office_run):
    """The twist is the step over dt and its covariance the step's over dt^2."""
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    previous = pipeline.process(office_run.scans[0])
    assert previous.step_covariance is None
    for scan in office_run.scans[1:6]:
        estimate = pipeline.process(scan)
        step = se2.relative(previous.pose, estimate.pose)
        np.testing.assert_allclose(estimate.twist, step / 0.1, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(estimate.twist_covariance,
                                   estimate.step_covariance / 0.01, rtol=1e-9)
        assert np.all(np.diag(estimate.step_covariance) > 0.0)
        previous = estimate


def test_pose_covariance_compounds_the_matchers_error_model(office_run):
    """Matched steps compound with the matcher's declared shares (plicp: shared scan, bias).

    The pose covariance is the propagation of each step's covariance from the previous
    pose, with StepErrorModel.of(matcher config) for a matched step.
    """
    from laser_odom.core.pose_uncertainty import PoseUncertainty, StepErrorModel
    pipeline = OdometryPipeline(PipelineConfig(matcher='plicp'))
    model = StepErrorModel.of(pipeline.matcher.config)
    assert model.shared_scan > 0.0 and model.bias_share > 0.0
    previous = pipeline.process(office_run.scans[0])
    expected = PoseUncertainty.at(np.zeros((3, 3)))
    white = PoseUncertainty.at(np.zeros((3, 3)))
    for scan in office_run.scans[1:8]:
        estimate = pipeline.process(scan)
        assert estimate.status == 'matched'
        step = se2.relative(previous.pose, estimate.pose)
        expected = expected.propagate(previous.pose, step, estimate.step_covariance, model)
        white = white.propagate(previous.pose, step, estimate.step_covariance,
                                StepErrorModel())
        np.testing.assert_allclose(estimate.pose_covariance, expected.pose_covariance,
                                   rtol=1e-9, atol=1e-15)
        previous = estimate
    assert not np.allclose(expected.pose_covariance, white.pose_covariance, rtol=0.05)


def test_first_scan_is_the_reference_at_rest():
    """An initialized estimate: the start pose, no twist, a tiny twist covariance."""
    scan = simulate('office', duration=0.1, seed=3).scans[0]
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    pipeline.reset(se2.pose(1.0, 2.0, 0.5), np.eye(3) * 0.01)
    estimate = pipeline.process(scan)
    assert estimate.status == 'initialized' and estimate.step_covariance is None
    np.testing.assert_array_equal(estimate.pose, [1.0, 2.0, 0.5])
    np.testing.assert_array_equal(estimate.pose_covariance, np.eye(3) * 0.01)
    np.testing.assert_array_equal(estimate.twist, np.zeros(3))
    np.testing.assert_array_equal(estimate.twist_covariance, np.eye(3) * 1e-6)


def test_processing_time_is_the_time_spent_in_process(office_run):
    """processing_time lies within the wall time of the call; prepare_next adds its own."""
    import time
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    for scan in office_run.scans[:3]:
        pipeline.process(scan)
        pipeline.prepare_next()
    started = time.perf_counter()
    estimate = pipeline.process(office_run.scans[3])
    took = time.perf_counter() - started
    assert 0.0 < estimate.processing_time <= took
    assert pipeline.processing_times[-1] == estimate.processing_time
    started = time.perf_counter()
    prepared = pipeline.prepare_next()
    took = time.perf_counter() - started
    assert 0.0 < prepared <= took
    assert pipeline.processing_times[-1] == pytest.approx(
        estimate.processing_time + prepared, rel=1e-12)


def test_time_jump_back_is_said_with_both_stamps(office_run):
    """The reset on a stamp earlier than the last one says both stamps in seconds."""
    from laser_odom.core.events import EventLog
    said = []
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'), events=EventLog(said.append))
    scans = office_run.scans
    for scan in (scans[5], scans[6], scans[2]):
        pipeline.process(scan)
    t6, t2 = scans[6].stamp_ns * 1e-9, scans[2].stamp_ns * 1e-9
    assert said == [f'scan stamp t={t2:.3f} is earlier than the previous t={t6:.3f} (bag '
                    'loop or restarted clock): odometry reset to the origin']


@pytest.mark.parametrize('rejected_motion', ['predict', 'hold'])
def test_a_rejection_stops_the_robot_distrusts_the_prediction_and_says_what_it_did(
        office_run, rejected_motion):
    """After a rejection: velocity zero, prediction untrusted, the action said.

    The message names the stamp and whether the pose advanced by the prediction or held.
    """
    from laser_odom.core.events import EventLog
    said = []
    config = PipelineConfig(matcher='icp')
    config.search.global_search = 'off'
    config.acceptance.rejected_motion = rejected_motion
    pipeline = OdometryPipeline(config, events=EventLog(said.append))
    for scan in office_run.scans[:5]:
        pipeline.process(scan)
    velocity = pipeline.motion.velocity.copy()
    before = pipeline.pose.copy()
    pipeline.config.acceptance.max_correction_linear = 1e-9
    estimate = pipeline.process(office_run.scans[5])
    assert estimate.status == 'rejected'
    np.testing.assert_array_equal(pipeline.motion.velocity, np.zeros(3))
    assert pipeline.untrusted == 'rejected'
    assert pipeline.counters['rejected'] == 1
    assert pipeline.counters['rejected_large_correction'] == 1
    advance = velocity * 0.1 if rejected_motion == 'predict' else np.zeros(3)
    np.testing.assert_allclose(estimate.pose, se2.compose(before, advance), atol=1e-12)
    at = f't={office_run.scans[5].stamp_ns * 1e-9:.3f}'
    action = ('advancing by the prediction' if rejected_motion == 'predict'
              else 'holding the pose')
    assert said[-1].startswith(f'match at {at} rejected (')
    assert said[-1].endswith(f'; {action}')
    # The scan is the new reference: the next match is against it, from rest.
    assert pipeline.keyframe.stamp_ns == office_run.scans[5].stamp_ns


def test_a_rejection_with_no_prior_says_it_holds_the_pose(office_run):
    """With prior none there is no prediction to advance by; the message says so."""
    from laser_odom.core.events import EventLog
    said = []
    config = PipelineConfig(matcher='icp')
    config.motion.prior = 'none'
    config.search.global_search = 'off'
    config.acceptance.max_correction_linear = 1e-9
    pipeline = OdometryPipeline(config, events=EventLog(said.append))
    for scan in office_run.scans[:2]:
        estimate = pipeline.process(scan)
    assert estimate.status == 'rejected'
    assert said[-1].endswith('; holding the pose (prior none: no prediction to advance by)')


def test_a_rejected_step_compounds_white_whatever_the_matchers_shares(office_run):
    """A rejected step's covariance is ignorance: propagated with the white model."""
    from laser_odom.core.acceptance import REJECTED_VARIANCE
    from laser_odom.core.pose_uncertainty import PoseUncertainty, StepErrorModel
    config = PipelineConfig(matcher='plicp')
    config.search.global_search = 'off'
    pipeline = OdometryPipeline(config)
    model = StepErrorModel.of(pipeline.matcher.config)
    estimates = [pipeline.process(scan) for scan in office_run.scans[:3]]
    expected = PoseUncertainty.at(np.zeros((3, 3)))
    for previous, estimate in zip(estimates, estimates[1:]):
        step = se2.relative(previous.pose, estimate.pose)
        expected = expected.propagate(previous.pose, step, estimate.step_covariance, model)
    pipeline.config.acceptance.max_correction_linear = 1e-9
    rejected = pipeline.process(office_run.scans[3])
    assert rejected.status == 'rejected'
    np.testing.assert_array_equal(rejected.step_covariance, np.diag(REJECTED_VARIANCE))
    step = se2.relative(estimates[-1].pose, rejected.pose)
    white = expected.propagate(estimates[-1].pose, step, rejected.step_covariance,
                               StepErrorModel())
    shared = expected.propagate(estimates[-1].pose, step, rejected.step_covariance, model)
    np.testing.assert_allclose(rejected.pose_covariance, white.pose_covariance, rtol=1e-9)
    assert not np.allclose(white.pose_covariance, shared.pose_covariance, rtol=1e-3)


@pytest.fixture(scope='module')
def turning_run():
    """Three seconds of driving at 0.3 m/s and turning at 0.8 rad/s (no sweep timing)."""
    from laser_odom.core.simulation.motions import ConstantTwist
    return simulate('office', 3.0, motion=ConstantTwist(0.3, 0.8, (1.0, 0.5, 0.0)), seed=1)


@pytest.mark.parametrize('distance, angle', [(0.25, 0.0), (0.0, 0.2), (0.25, 100.0)])
def test_keyframe_is_replaced_once_the_robot_moved_or_turned_far_enough(
        turning_run, distance, angle):
    """The reference is kept until the distance or the angle from it reaches its setting.

    A setting of 0 is off (both 0: scan to scan).
    """
    config = PipelineConfig(matcher='icp')
    config.keyframes.keyframe_distance = distance
    config.keyframes.keyframe_angle = angle
    pipeline = OdometryPipeline(config)
    pipeline.process(turning_run.scans[0])
    replaced = 0
    for scan in turning_run.scans[1:]:
        keyframe, keyframe_pose = pipeline.keyframe, pipeline.keyframe_pose.copy()
        estimate = pipeline.process(scan)
        assert estimate.status == 'matched'
        offset = se2.relative(keyframe_pose, estimate.pose)
        far = ((distance > 0.0 and np.hypot(offset[0], offset[1]) >= distance)
               or (angle > 0.0 and abs(offset[2]) >= angle))
        assert (pipeline.keyframe is not keyframe) == far, (distance, angle, offset)
        replaced += far
    assert 3 <= replaced <= 15
    scan_to_scan = OdometryPipeline(PipelineConfig(matcher='icp'))
    for scan in turning_run.scans[:4]:
        scan_to_scan.process(scan)
        assert scan_to_scan.keyframe.stamp_ns == scan.stamp_ns


def test_configure_keeps_or_replaces_the_matcher_and_the_reference(office_run):
    """A new matcher or matcher setting replaces the matcher; a new mounting the reference.

    Same settings: the same matcher and reference. A new mounting drops the reference
    and integration restarts from the current pose.
    """
    import copy
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    for scan in office_run.scans[:5]:
        pipeline.process(scan)
    matcher, keyframe, pose = pipeline.matcher, pipeline.keyframe, pipeline.pose.copy()
    pipeline.configure(copy.deepcopy(pipeline.config))
    assert pipeline.matcher is matcher and pipeline.keyframe is keyframe
    config = copy.deepcopy(pipeline.config)
    config.matcher_config.max_iterations += 7
    pipeline.configure(config)
    assert pipeline.matcher is not matcher and pipeline.matcher.name == 'icp'
    assert pipeline.matcher.config.max_iterations == matcher.config.max_iterations + 7
    assert pipeline.keyframe is keyframe
    config = copy.deepcopy(pipeline.config)
    config.matcher, config.matcher_config = 'plicp', None
    pipeline.configure(config)
    assert pipeline.matcher.name == 'plicp' and pipeline.keyframe is keyframe
    assert pipeline.process(office_run.scans[5]).status == 'matched'
    config = copy.deepcopy(pipeline.config)
    config.mounting.laser_x = 0.1
    moved = pipeline.pose.copy()
    assert np.hypot(*(moved - pose)[:2]) > 0.01
    pipeline.configure(config)
    assert pipeline.keyframe is None
    estimate = pipeline.process(office_run.scans[6])
    assert estimate.status == 'initialized'
    np.testing.assert_array_equal(estimate.pose, moved)


def swept_run(stamp_at: str):
    """Three seconds of a 5 Hz LDS-01 turning at 1.5 rad/s: each sweep is bent by 0.3 rad."""
    from laser_odom.core.simulation.motions import ConstantTwist
    from laser_odom.core.simulation.sensors import sensor_model
    return simulate('office', 3.0, sensor_model('lds01', stamp_at=stamp_at),
                    motion=ConstantTwist(0.3, 1.5, (1.0, 0.5, 0.0)), seed=1)


def swept_pipeline(deskew='auto', prior='constant_velocity', stamp='first_beam',
                   global_search='recover'):
    """Return an icp pipeline and the number of matcher calls it made for each scan."""
    config = PipelineConfig(matcher='icp')
    config.scan.deskew, config.scan.scan_stamp = deskew, stamp
    config.motion.prior, config.search.global_search = prior, global_search
    pipeline = OdometryPipeline(config)
    calls = []
    match = pipeline.matcher.match

    def counted(*args, **kwargs):
        calls.append(1)
        return match(*args, **kwargs)
    pipeline.matcher.match = counted
    return pipeline, calls


def step_rotation_errors(estimates, truth) -> np.ndarray:
    poses = np.array([estimate.pose for estimate in estimates])
    return np.array([abs(se2.wrap_angle(se2.relative(poses[k - 1], poses[k])[2]
                                        - se2.relative(truth[k - 1], truth[k])[2]))
                     for k in range(1, len(poses))])


def test_without_a_prediction_the_measured_twist_deskews_the_scans_and_matches_again():
    """Prior none: the scans are de-skewed with the twist the first match measures.

    Matched again, the step rotation errors fall from 14 mrad (the sweep's bend) to 2.
    """
    data = swept_run('first')
    errors = {}
    for deskew in ('off', 'auto'):
        pipeline, _ = swept_pipeline(deskew, prior='none')
        estimates = [pipeline.process(scan) for scan in data.scans]
        assert [e.status for e in estimates[1:]] == ['matched'] * (len(data.scans) - 1)
        errors[deskew] = step_rotation_errors(estimates, data.reference.poses).mean()
    assert errors['off'] > 0.01
    assert errors['auto'] < 0.004 and errors['auto'] < 0.3 * errors['off']


@pytest.mark.parametrize('stamp_at', ['first', 'last'])
def test_a_good_prediction_is_not_matched_again(stamp_at):
    """With a constant-velocity prediction most scans need one match (the twist agrees).

    Stamped at the first beam the keyframe is de-skewed with the prediction before the
    match; stamped at the last its sweep is already known.
    """
    data = swept_run(stamp_at)
    pipeline, calls = swept_pipeline(stamp=f'{stamp_at}_beam')
    counts = []
    for scan in data.scans:
        before = len(calls)
        assert pipeline.process(scan).status in ('initialized', 'matched')
        counts.append(len(calls) - before)
    assert counts[1] >= 2  # the first step: the reference's sweep is not known yet
    assert sum(count == 1 for count in counts[5:]) >= 5, str(counts)  # of 10


def test_the_first_match_is_kept_when_the_match_again_is_rejected():
    """A second match (after de-skewing with the measured twist) that fails is dropped."""
    data = swept_run('first')
    pipeline, calls = swept_pipeline(global_search='off')
    pipeline.process(data.scans[0])
    real = pipeline.matcher.match
    results = []

    def second_fails(reference, current, guess):
        results.append(real(reference, current, guess))
        if len(results) > 1:
            results[-1].converged = False
        return results[-1]
    pipeline.matcher.match = second_fails
    estimate = pipeline.process(data.scans[1])
    assert len(results) == 2 and estimate.status == 'matched'
    assert estimate.match is results[0]
    np.testing.assert_allclose(estimate.pose, results[0].pose, atol=1e-12)  # from the origin
    assert not np.allclose(results[1].pose, results[0].pose, rtol=0.0, atol=1e-6)


@pytest.mark.parametrize('stamp_at', ['first', 'last'])
def test_a_keyframe_whose_sweep_follows_its_stamp_is_not_prepared(stamp_at):
    """Stamped at the first beam, a keyframe is de-skewed again: prepare_next skips it.

    Its sweep is measured by the next match, which de-skews it again. Stamped at the
    last beam it is prepared.
    """
    data = swept_run(stamp_at)
    pipeline, _ = swept_pipeline(stamp=f'{stamp_at}_beam')
    assert pipeline.process(data.scans[0]).status == 'initialized'
    assert pipeline.prepare_next() == 0.0  # its motion is not known yet
    for scan in data.scans[1:6]:
        assert pipeline.process(scan).status == 'matched'
        assert (pipeline.prepare_next() > 0.0) == (stamp_at == 'last')
        assert pipeline.keyframe_prepared == (stamp_at == 'last')


def test_keyframe_expires_at_exactly_its_distance_or_angle():
    """The distance and angle settings are reached inclusively; 0 switches one off."""
    config = PipelineConfig(matcher='icp')
    pipeline = OdometryPipeline(config)
    expired = pipeline._keyframe_expired
    assert expired(se2.pose()) and expired(se2.pose(0.001, 0.0, 0.0))  # both 0: always
    config.keyframes.keyframe_distance, config.keyframes.keyframe_angle = 0.5, 0.0
    assert expired(se2.pose(0.3, -0.4, 0.0)) and not expired(se2.pose(0.3, 0.399, 3.0))
    config.keyframes.keyframe_distance, config.keyframes.keyframe_angle = 0.0, 0.25
    assert expired(se2.pose(0.0, 0.0, -0.25)) and not expired(se2.pose(9.0, 9.0, 0.249))
    config.keyframes.keyframe_distance = 0.5
    assert expired(se2.pose(0.5, 0.0, 0.0)) and expired(se2.pose(0.0, 0.0, 0.25))
    assert not expired(se2.pose(0.49, 0.0, 0.24))


def test_a_skipped_scan_is_said_with_its_stamp_and_reason(office_run):
    """A scan rejected by validation is counted under its reason and said with its stamp."""
    from laser_odom.core.events import EventLog
    said = []
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'), events=EventLog(said.append))
    scan = office_run.scans[7]
    empty = LaserScan(scan.stamp_ns, scan.angle_min, scan.angle_max, scan.angle_increment,
                      scan.range_min, scan.range_max, np.zeros(0))
    assert pipeline.process(empty) is None
    assert pipeline.counters['empty_scan'] == 1 and pipeline.counters['processed'] == 0
    assert said == [f'scan at t={scan.stamp_ns * 1e-9:.3f} skipped: scan has no ranges']


def good_match(pose=(0.0, 0.0, 0.0), **fields):
    """Return a converged, well-paired, well-constrained match at ``pose``."""
    from laser_odom.core.matchers import MatchResult
    values = {'pose': np.array(pose, dtype=float), 'converged': True, 'iterations': 5,
              'inlier_ratio': 0.9, 'residual': 0.01, 'information': np.diag([1e4, 2e4, 3e4]),
              'covariance': np.diag([1e-4, 5e-5, 1e-5])}
    values.update(fields)
    return MatchResult(**values)


def test_acceptance_gates_the_correction_inclusively_in_the_predictions_frame():
    """max_correction_* are inclusive and measured from the guess, in its frame.

    Non-finite poses or covariances are rejected before the correction is judged.
    """
    from laser_odom.core.acceptance import correction_from, rejection_reason
    from laser_odom.core.config import AcceptanceConfig
    config = AcceptanceConfig(max_correction_linear=0.5, max_correction_angular=0.25)
    zero = se2.pose()
    for pose, reason in (((0.5, 0.0, 0.0), None), ((0.0, -0.5, 0.25), None),
                         ((0.0, 0.0, -0.25), None), ((0.5000001, 0.0, 0.0), 'large_correction'),
                         ((0.0, 0.0, 0.2500001), 'large_correction'),
                         ((0.0, 0.0, -0.2500001), 'large_correction')):
        assert rejection_reason(good_match(pose), zero, config) == reason, pose
    guess = se2.pose(2.0, 1.0, math.pi / 2)
    pose = se2.compose(guess, se2.pose(0.3, 0.39, 0.2))
    linear, angular = correction_from(guess, pose)
    assert linear == pytest.approx(math.hypot(0.3, 0.39), abs=1e-12)
    assert angular == pytest.approx(0.2, abs=1e-12)
    assert rejection_reason(good_match(pose), guess, config) is None
    far = se2.compose(guess, se2.pose(0.3, 0.41, 0.0))
    assert rejection_reason(good_match(far), guess, config) == 'large_correction'
    nan_pose = good_match((math.nan, 0.0, 0.0))
    assert rejection_reason(nan_pose, zero, config) == 'non_finite'
    inf_covariance = good_match(covariance=np.diag([1e-4, math.inf, 1e-5]))
    assert rejection_reason(inf_covariance, zero, config) == 'non_finite'
    bad = good_match((math.nan, 0.0, 0.0), converged=False, inlier_ratio=0.0)
    assert rejection_reason(bad, zero, config) == 'not_converged'
    assert rejection_reason(good_match((9.0, 0.0, 0.0), inlier_ratio=0.1), zero,
                            config) == 'low_inlier_ratio'


def test_a_searched_match_is_gated_by_the_window_and_its_surface_overlap():
    """The search window plus one cell is inclusive in x, y and the wrapped angle.

    The inlier ratio judged is the surface overlap the search measured, if there is one.
    """
    from laser_odom.core.acceptance import searched_inlier_ratio, searched_rejection_reason
    from laser_odom.core.config import AcceptanceConfig
    from laser_odom.core.search import SearchWindow
    config = AcceptanceConfig(min_inlier_ratio=0.3)
    window = SearchWindow(linear=1.0, angular=0.5, resolution=0.25)
    guess = se2.pose(1.0, -2.0, 3.0)
    for offset, reason in (((1.25, 0.0, 0.0), None), ((0.0, -1.25, 0.0), None),
                           ((0.0, 0.0, 0.75), None), ((-1.25, 1.25, -0.75), None),
                           ((1.2500001, 0.0, 0.0), 'outside_window'),
                           ((0.0, -1.2500001, 0.0), 'outside_window'),
                           ((0.0, 0.0, -0.7500001), 'outside_window')):
        match = good_match(guess + np.array(offset))
        assert searched_rejection_reason(match, guess, config, window) == reason, offset
    wrapped = good_match(guess + np.array([0.0, 0.0, 0.7 - 2.0 * math.pi]))
    assert searched_rejection_reason(wrapped, guess, config, window) is None
    sparse = good_match(guess, inlier_ratio=0.1, extra={'surface_overlap': 0.3})
    assert searched_inlier_ratio(sparse) == 0.3
    assert searched_rejection_reason(sparse, guess, config, window) is None
    apart = good_match(guess, inlier_ratio=0.9, extra={'surface_overlap': 0.29})
    assert searched_rejection_reason(apart, guess, config, window) == 'low_overlap'
    plain = good_match(guess, inlier_ratio=0.29)
    assert searched_inlier_ratio(plain) == 0.29
    assert searched_rejection_reason(plain, guess, config, window) == 'low_overlap'
    failed = good_match(guess, converged=False)
    assert searched_rejection_reason(failed, guess, config, window) == 'not_converged'


def test_each_rejection_is_described_with_its_numbers():
    """The log line of each reason carries the figures behind it."""
    from laser_odom.core.acceptance import describe_rejection
    config = PipelineConfig()
    config.acceptance.min_inlier_ratio = 0.3
    config.acceptance.max_correction_linear = 0.5
    config.acceptance.max_correction_angular = math.radians(20.0)
    config.search.global_search_linear = 1.5
    config.search.global_search_angular = math.radians(45.0)
    guess = se2.pose(1.0, 1.0, math.pi / 2)
    match = good_match(se2.compose(guess, se2.pose(0.6, -0.8, math.radians(30.0))),
                       iterations=17, inlier_ratio=0.25, extra={'surface_overlap': 0.125})
    assert describe_rejection('not_converged', match, guess, config) == (
        'not converged after 17 iterations')
    assert describe_rejection('low_inlier_ratio', match, guess, config) == (
        '25% of the points paired, min_inlier_ratio 30%')
    assert describe_rejection('low_overlap', match, guess, config) == (
        '12% of the points on the reference surface, min_inlier_ratio 30%')
    assert describe_rejection('large_correction', match, guess, config) == (
        '1.00 m / 30.0 deg from the prediction, gate 0.50 m / 20.0 deg')
    assert describe_rejection('outside_window', match, guess, config) == (
        '1.00 m / 30.0 deg from the prediction, outside the search window +-1.50 m / '
        '+-45.0 deg')
    assert describe_rejection('non_finite', match, guess, config) == 'non finite'
    # A reason without figures of its own (a local failure against a usual level of 0).
    assert describe_rejection('high_residual', match, guess, config) == 'high residual'
    assert describe_rejection('few_inliers', match, guess, config) == 'few inliers'
    assert describe_rejection('unknown', match, guess, config) == 'unknown'


def test_judge_match_rejects_to_the_prediction_or_holds():
    """A rejected match is replaced by the guess (or no motion) with REJECTED_VARIANCE."""
    from laser_odom.core.acceptance import judge_match, REJECTED_VARIANCE
    from laser_odom.core.registration import Registration
    config = PipelineConfig()
    guess = se2.pose(0.1, 0.02, 0.01)
    # ''.join: the name as a parameter file gives it (equal, not the same object).
    for motion, expected in (('predict', guess), (''.join(list('predict')), guess),
                             ('hold', se2.pose())):
        config.acceptance.rejected_motion = motion
        match = good_match(guess, converged=False)
        verdict = judge_match(Registration(match), guess, config)
        assert verdict.status == 'rejected' and match.extra['rejection'] == 'not_converged'
        np.testing.assert_array_equal(verdict.pose, expected)
        np.testing.assert_array_equal(verdict.covariance, np.diag(REJECTED_VARIANCE))
        # The declared values: a standard deviation of 0.5 m and 0.5 rad per axis.
        np.testing.assert_array_equal(verdict.covariance, np.diag([0.25, 0.25, 0.25]))
    # A searched match is judged by the window: 2 m off the guess is outside 1.5 m + 0.1.
    config.acceptance.max_correction_linear = 5.0
    far = good_match(guess + np.array([1.65, 0.0, 0.0]))
    assert judge_match(Registration(far), guess, config).status == 'matched'
    searched = judge_match(Registration(far, trigger='reset', trusted=False), guess, config)
    assert searched.status == 'rejected' and far.extra['rejection'] == 'outside_window'
    near = good_match(guess + np.array([1.55, 0.0, 0.0]))
    assert judge_match(Registration(near, trigger='reset'), guess, config).status == 'matched'


def test_judge_match_keeps_the_prediction_along_a_degenerate_direction():
    """Weak along x: x keeps the anchor with DEGENERATE_VARIANCE, y and yaw the match's.

    The anchor is the guess when the prediction is trusted, else the match itself.
    """
    from laser_odom.core.acceptance import DEGENERATE_VARIANCE, judge_match
    from laser_odom.core.registration import Registration
    config = PipelineConfig()
    config.acceptance.degeneracy_min_information = 400.0
    config.acceptance.max_correction_angular = 1.0
    length = 2.0
    information = np.diag([100.0, 1e4, 2e4 * length ** 2])  # metric: 100, 1e4, 2e4 1/m^2
    guess = se2.pose(1.0, 2.0, 3.1)
    pose = se2.pose(1.3, 2.2, -3.1)  # 0.083 rad from the guess, across the wrap
    match = good_match(pose, information=information)
    verdict = judge_match(Registration(match), guess, config, length)
    assert verdict.status == 'degenerate' and match.degenerate
    np.testing.assert_allclose(verdict.pose, [1.0, 2.2, -3.1], atol=1e-12)
    expected = np.diag([DEGENERATE_VARIANCE, 1e-4, 1.0 / 2e4 / length ** 2])
    np.testing.assert_allclose(verdict.covariance, expected, rtol=1e-9, atol=1e-15)
    assert verdict.covariance[0, 0] == 1.0  # as uncertain as the prior: 1 m^2
    untrusted = good_match(pose, information=information)
    verdict = judge_match(Registration(untrusted, trigger='reset', trusted=False), guess,
                          config, length)
    assert verdict.status == 'degenerate'
    np.testing.assert_allclose(verdict.pose, pose, atol=1e-12)
    strong = good_match(pose, information=np.diag([400.0, 1e4, 1e4 * length ** 2]))
    verdict = judge_match(Registration(strong), guess, config, length)
    assert verdict.status == 'matched' and not strong.degenerate
    np.testing.assert_array_equal(verdict.pose, pose)
    np.testing.assert_array_equal(verdict.covariance, strong.covariance)
    assert verdict.pose is not strong.pose and verdict.covariance is not strong.covariance


def test_an_ambiguous_match_covers_its_alternatives():
    """Each alternative's offset (angle wrapped) is added as d d^T: reported degenerate."""
    from laser_odom.core.acceptance import covering_covariance, judge_match
    from laser_odom.core.registration import Registration
    config = PipelineConfig()
    pose = se2.pose(1.0, 2.0, 3.0)
    covariance = np.diag([1e-4, 2e-4, 3e-5])
    alternatives = [se2.pose(1.5, 2.0, 3.0), se2.pose(1.0, 1.8, 3.2 - 2.0 * math.pi)]
    d1, d2 = np.array([0.5, 0.0, 0.0]), np.array([0.0, -0.2, 0.2])
    expected = covariance + np.outer(d1, d1) + np.outer(d2, d2)
    covering = covering_covariance(pose, covariance, alternatives)
    np.testing.assert_allclose(covering, expected, atol=1e-12)
    for alternative in alternatives:  # each within one standard deviation
        d = alternative - pose
        d[2] = se2.wrap_angle(d[2])
        assert d @ np.linalg.solve(covering, d) < 1.0
    match = good_match(pose, covariance=covariance)
    registration = Registration(match, trigger='reset', trusted=False,
                                alternatives=[(a, 0.95) for a in alternatives])
    verdict = judge_match(registration, pose, config)
    assert verdict.status == 'degenerate' and match.extra['ambiguous']
    np.testing.assert_allclose(verdict.covariance, expected, atol=1e-12)
    np.testing.assert_array_equal(verdict.pose, pose)


def test_a_stamp_equal_to_the_last_is_a_duplicate_even_as_another_int_object(office_run):
    """Stamps from a driver are new int objects each time: equal is what counts."""
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    for scan in office_run.scans[:3]:
        pipeline.process(scan)
    again = replace_stamp(office_run.scans[2], int(str(office_run.scans[2].stamp_ns)))
    assert again.stamp_ns is not office_run.scans[2].stamp_ns
    assert pipeline.process(again) is None
    assert pipeline.counters['duplicate_stamp'] == 1 and pipeline.counters['processed'] == 3


def test_switching_the_matcher_type_forgets_how_matches_usually_fit(office_run):
    """The usual residual and inlier ratio belong to one matcher's metric."""
    from laser_odom.core.matchers import matcher_class
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    for scan in office_run.scans[:12]:
        pipeline.process(scan)
    usual = pipeline.registrar.usual
    residual = usual.residual()
    assert residual is not None and usual.inlier_ratio() is not None
    pipeline.set_matcher(matcher_class('icp')(pipeline.matcher.config))
    assert usual.residual() == residual  # another icp: the same metric
    pipeline.set_matcher(matcher_class('plicp')(PipelineConfig(
        matcher='plicp').resolved_matcher_config()))
    assert usual.residual() is None and usual.inlier_ratio() is None
    assert pipeline.config.matcher == 'plicp'


def test_a_degenerate_step_compounds_white_whatever_the_matchers_shares(office_run):
    """A degenerate match's covariance is ignorance: propagated with the white model."""
    from laser_odom.core.pose_uncertainty import PoseUncertainty, StepErrorModel
    config = PipelineConfig(matcher='plicp')
    config.acceptance.degeneracy_min_information = 1e12  # every direction weak
    pipeline = OdometryPipeline(config)
    assert StepErrorModel.of(pipeline.matcher.config).shared_scan > 0.0
    estimates = [pipeline.process(scan) for scan in office_run.scans[:5]]
    white = PoseUncertainty.at(np.zeros((3, 3)))
    for previous, estimate in zip(estimates, estimates[1:]):
        assert estimate.status == 'degenerate'
        step = se2.relative(previous.pose, estimate.pose)
        white = white.propagate(previous.pose, step, estimate.step_covariance,
                                StepErrorModel())
        np.testing.assert_allclose(estimate.pose_covariance, white.pose_covariance,
                                   rtol=1e-9)


def test_a_rejected_scan_becomes_the_reference_even_between_keyframes(office_run):
    """After a rejection the current scan is the reference, whatever the keyframe rules."""
    config = PipelineConfig(matcher='icp')
    config.search.global_search = 'off'
    config.keyframes.keyframe_distance = 5.0
    pipeline = OdometryPipeline(config)
    for scan in office_run.scans[:4]:
        pipeline.process(scan)
    assert pipeline.keyframe.stamp_ns == office_run.scans[0].stamp_ns
    pipeline.config.acceptance.max_correction_linear = 1e-9
    assert pipeline.process(office_run.scans[4]).status == 'rejected'
    assert pipeline.keyframe.stamp_ns == office_run.scans[4].stamp_ns
    np.testing.assert_array_equal(pipeline.keyframe_pose, pipeline.pose)


@pytest.mark.parametrize('rejected_motion', ['predict', 'hold'])
def test_a_rejected_match_is_not_deskewed_and_matched_again(rejected_motion):
    """A rejection stands: the pose it gives (prediction or hold) is not re-matched."""
    data = swept_run('first')
    pipeline, _ = swept_pipeline(global_search='off')
    pipeline.config.acceptance.rejected_motion = rejected_motion
    for scan in data.scans[:4]:
        pipeline.process(scan)
    real = pipeline.matcher.match
    results = []

    def first_fails(reference, current, guess):
        results.append(real(reference, current, guess))
        if len(results) == 1:
            results[-1].converged = False
        return results[-1]
    pipeline.matcher.match = first_fails
    assert pipeline.process(data.scans[4]).status == 'rejected'
    assert len(results) == 1


def test_a_keyframe_with_a_known_sweep_is_not_deskewed_again():
    """Stamped at the last beam, a held keyframe keeps its de-skewing when scans re-match."""
    data = swept_run('last')
    pipeline, calls = swept_pipeline(stamp='last_beam')
    pipeline.config.keyframes.keyframe_distance = 10.0
    pipeline.process(data.scans[0])
    pipeline.process(data.scans[1])  # the first match measures the reference's sweep
    keyframe = pipeline.keyframe
    counts = []
    for scan in data.scans[2:7]:
        before = len(calls)
        assert pipeline.process(scan).status == 'matched'
        counts.append(len(calls) - before)
        assert pipeline.keyframe is keyframe
    assert max(counts) >= 2  # some scans were de-skewed and matched again


def test_processing_time_statistics_cover_the_last_thousand_scans():
    """The node's timing diagnostics read the last TIMING_WINDOW = 1000 processing times."""
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    pipeline.processing_times.extend(float(k) for k in range(1200))
    assert len(pipeline.processing_times) == 1000
    assert pipeline.processing_times[0] == 200.0 and pipeline.processing_times[-1] == 1199.0


def test_an_odometry_prior_is_trusted_and_a_rejection_advances_by_it(office_run):
    """With prior odom the matches start from the wheel odometry: no search after the first.

    A rejection then advances by that prediction, and says so.
    """
    from laser_odom.core.events import EventLog
    said = []
    config = PipelineConfig(matcher='icp')
    config.motion.prior = 'odom'
    pipeline = OdometryPipeline(config, events=EventLog(said.append))
    truth = office_run.reference.poses
    for k, scan in enumerate(office_run.scans[:6]):
        prior = se2.relative(truth[k - 1], truth[k]) if k else None
        estimate = pipeline.process(scan, prior_step=prior)
        assert estimate.status in ('initialized', 'matched')
    assert pipeline.counters['search_reset'] == 1
    assert pipeline.counters['search_no_prior'] == 0
    pipeline.config.acceptance.max_correction_linear = 1e-9
    pipeline.config.search.global_search = 'off'
    prior = se2.relative(truth[5], truth[6])
    before = pipeline.pose.copy()
    assert pipeline.process(office_run.scans[6], prior_step=prior).status == 'rejected'
    np.testing.assert_allclose(pipeline.pose, se2.compose(before, prior), atol=1e-12)
    assert said[-1].endswith('; advancing by the prediction')


def test_settings_named_as_a_parameter_file_gives_them_act_like_the_literals(office_run):
    """Equal strings that are not the same object: prior none, predict, the matcher name."""
    from laser_odom.core.events import EventLog
    said = []
    config = PipelineConfig(matcher='icp')
    config.motion.prior = ''.join(list('none'))
    config.acceptance.rejected_motion = ''.join(list('predict'))
    pipeline = OdometryPipeline(config, events=EventLog(said.append))
    for scan in office_run.scans[:4]:
        pipeline.process(scan)
    assert pipeline.counters['search_no_prior'] == 3  # every match searched
    pipeline.config.acceptance.max_correction_linear = 1e-9
    pipeline.config.search.global_search = 'off'
    assert pipeline.process(office_run.scans[4]).status == 'rejected'
    assert said[-1].endswith('; holding the pose (prior none: no prediction to advance by)')
    matcher = pipeline.matcher
    import copy
    same = copy.deepcopy(pipeline.config)
    same.matcher = ''.join(list('icp'))
    pipeline.configure(same)
    assert pipeline.matcher is matcher
    predict = OdometryPipeline(PipelineConfig(matcher='icp'), events=EventLog(said.append))
    predict.config.acceptance.rejected_motion = ''.join(list('predict'))
    predict.config.acceptance.max_correction_linear = 1e-9
    predict.config.search.global_search = 'off'
    predict.process(office_run.scans[0])
    assert predict.process(office_run.scans[1]).status == 'rejected'
    assert said[-1].endswith('; advancing by the prediction')


def test_switching_to_any_other_matcher_type_forgets_the_usual_fit(office_run):
    """From plicp to icp as from icp to plicp: the usual fit is forgotten."""
    from laser_odom.core.matchers import matcher_class
    pipeline = OdometryPipeline(PipelineConfig(matcher='plicp'))
    for scan in office_run.scans[:12]:
        pipeline.process(scan)
    assert pipeline.registrar.usual.residual() is not None
    pipeline.set_matcher(matcher_class('icp')(PipelineConfig(
        matcher='icp').resolved_matcher_config()))
    assert pipeline.registrar.usual.residual() is None


def test_a_rejected_keyframe_is_not_prepared_its_sweep_is_unknown():
    """Stamped at the last beam, a scan that replaced a rejected match is de-skewed again."""
    data = swept_run('last')
    pipeline, _ = swept_pipeline(stamp='last_beam', global_search='off')
    for scan in data.scans[:3]:
        pipeline.process(scan)
    assert pipeline.prepare_next() > 0.0
    pipeline.config.acceptance.max_correction_linear = 1e-9
    assert pipeline.process(data.scans[3]).status == 'rejected'
    assert pipeline.keyframe.stamp_ns == data.scans[3].stamp_ns
    assert pipeline.prepare_next() == 0.0 and not pipeline.keyframe_prepared


def test_the_global_search_is_said_with_its_trigger_and_the_local_failure(office_run):
    """A search after a gap says the trigger; after a failed local match also the failure."""
    from laser_odom.core.events import EventLog
    said = []
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'), events=EventLog(said.append))
    scans = office_run.scans
    for scan in scans[:3]:
        pipeline.process(scan)
    late = replace_stamp(scans[3], scans[2].stamp_ns + 1_500_000_000)
    pipeline.process(late)
    at = f't={late.stamp_ns * 1e-9:.3f}'
    assert said[-1].startswith(f'global search at {at}: the motion prior was dropped after a '
                               'gap between scans; best of ')
    pipeline.config.acceptance.max_correction_linear = 1e-9  # the local match fails
    shifted = replace_stamp(scans[4], late.stamp_ns + 100_000_000)
    pipeline.process(shifted)
    at = f't={shifted.stamp_ns * 1e-9:.3f}'
    searches = [line for line in said if line.startswith(f'global search at {at}')]
    assert len(searches) == 1
    assert searches[0].startswith(f'global search at {at}: the match from the prediction '
                                  'failed (')


def test_a_direction_without_information_keeps_a_finite_variance():
    """With degeneracy_min_information 0, a zero eigenvalue's variance is 1e300, not 1 / 0.

    A zero eigenvalue is then not weak; a slightly negative one is (DEGENERATE_VARIANCE).
    """
    from laser_odom.core.acceptance import judge_match
    from laser_odom.core.registration import Registration
    config = PipelineConfig()
    config.acceptance.degeneracy_min_information = 0.0
    match = good_match(se2.pose(0.01, 0.0, 0.0), information=np.diag([-1e-9, 0.0, 1e4]))
    verdict = judge_match(Registration(match), se2.pose(), config, 1.0)
    assert verdict.status == 'degenerate'
    assert np.all(np.isfinite(verdict.covariance))
    np.testing.assert_allclose(np.diag(verdict.covariance), [1.0, 1e300, 1e-4], rtol=1e-12)
